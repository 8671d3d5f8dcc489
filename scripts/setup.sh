#!/usr/bin/env bash
# Set up ndfa on a fresh Debian machine: system libraries, a venv with the CPU build of torch,
# and the package itself (editable). Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${NDFA_VENV:-.venv}
PYTHON=${PYTHON:-python3}

# open3d needs libusb at import time, even headless.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    echo "[setup] installing libusb-1.0-0 (open3d needs it)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 libgomp1 >/dev/null
fi

# The web viewer's test (tests/test_viewer.py) opens `ndfa view --web` in Debian's Chromium, driven
# by Playwright (the dev extra) with its own executable_path: no browser download.
if [ ! -x /usr/bin/chromium ]; then
    echo "[setup] installing chromium (the web viewer's test)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
    echo "[setup] creating $VENV"
    "$PYTHON" -m venv "$VENV"
fi

# pip runs only when what it installs changed: the stamp holds a hash of the tables of pyproject.toml
# that decide the install (build-system, project, tool.setuptools). The tools' settings there
# (pytest, ruff, mypy, import-linter) do not, so editing them does not re-run pip.
stamp="$VENV/.ndfa-installed"
wanted=$("$VENV/bin/python" - <<'PY'
import hashlib, json, tomllib
with open("pyproject.toml", "rb") as file:
    pyproject = tomllib.load(file)
install = {key: pyproject.get(key) for key in ("build-system", "project")}
install["setuptools"] = pyproject.get("tool", {}).get("setuptools")
print(hashlib.sha256(json.dumps(install, sort_keys=True).encode()).hexdigest())
PY
)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$wanted" ]; then
    "$VENV/bin/pip" install -q --upgrade pip
    # The pinned CPU build first: a looser spec would pull a multi-GB CUDA build.
    "$VENV/bin/pip" install -q torch==2.13.0
    # dev: the test and lint tools; cluster: Ray, so that `make test` also runs the sweep's
    # fault test on a real two-node cluster (tests/test_sweep_cluster.py).
    "$VENV/bin/pip" install -q -e '.[dev,cluster]'
    echo "$wanted" > "$stamp"
fi
echo "[setup] ready: $VENV/bin/ndfa"
