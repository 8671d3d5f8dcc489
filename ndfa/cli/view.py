"""`ndfa view`: open a run's .rrd in Rerun's viewer, on this machine's display or, with `--web`, in a
browser anywhere (Rerun's web viewer, bundled with rerun-sdk, served from here).

Both run Rerun's own command line (`python -m rerun_cli`) as a child process. The web mode serves
two ports: PORT, the viewer's page (HTTP), and PORT + 1, the gRPC server the page streams the
recording from; a browser on another machine reaches both through one `ssh -L` per port.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import quote

import typer

from ndfa.cli.app import app, console, err_console
from ndfa.cli.checks import in_range
from ndfa.core.errors import ViewerError

DEFAULT_PORT = 9090  # Rerun's own default for its web viewer page
SERVER_START_S = 60.0  # the server answers within a second or two; a loaded machine can take longer


@app.command("view")
def view_command(
    rrd: Path = typer.Argument(..., help="A Rerun recording written by `ndfa detect --log`."),
    web: bool = typer.Option(False, "--web", help="Serve Rerun's web viewer and print its URL, instead of opening "
                             "a window: for a machine without a display (a server, over ssh)."),
    port: int = typer.Option(DEFAULT_PORT, help="--web: the viewer page's port; the recording streams from PORT + 1.",
                             callback=in_range(ge=1, le=65534)),
    bind: str = typer.Option("127.0.0.1", help="--web: the address to listen on. The default is reachable from "
                             "this machine only (and through ssh -L); 0.0.0.0 is every network interface."),
) -> None:
    """Open a .rrd in the Rerun viewer, in its own layout: the 3-D world, camera, decisions and timings."""
    if not rrd.is_file():
        raise ViewerError(f"{rrd}: no such file")
    if web:
        serve_web(rrd, port, bind)
    else:
        open_native(rrd)


def _rerun(*args: str) -> list[str]:
    """Rerun's command line, from the rerun-sdk that this Python has (not whichever `rerun` is on PATH)."""
    return [sys.executable, "-m", "rerun_cli", *args]


def _quiet_env() -> dict[str, str]:
    """Rerun logs every start-up step at INFO; warnings and errors are what a user needs."""
    return {**os.environ, "RUST_LOG": os.environ.get("RUST_LOG", "warn")}


def open_native(rrd: Path) -> None:
    """The desktop viewer. Without a display it cannot start: Rerun prints winit's error, several
    lines long, and nothing says what to do instead; so look before starting it, and turn its error,
    if it fails, into one line that does."""
    hint = f"use `ndfa view {rrd} --web` and open the URL it prints"
    if sys.platform.startswith("linux") and not any(os.environ.get(name) for name in
                                                     ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")):
        raise ViewerError(f"{rrd}: no display to open the Rerun viewer on (DISPLAY and WAYLAND_DISPLAY are unset): {hint}")
    viewer = subprocess.Popen(_rerun(str(rrd)), stderr=subprocess.PIPE, text=True, env=_quiet_env())
    error = ""
    assert viewer.stderr is not None
    for line in viewer.stderr:  # passed on as it comes, but its error goes into the one-line message
        if line.startswith("Error:"):
            error = line.rsplit(": ", 1)[-1].strip()  # winit's reason, without its source location
        else:
            sys.stderr.write(line)
    code = viewer.wait()
    if code != 0 or error:
        raise ViewerError(f"{rrd}: the Rerun viewer could not start ({error or f'exit code {code}'}): {hint}")


def viewer_url(host: str, port: int) -> str:
    """The page's address with the recording's stream (gRPC, PORT + 1) in its `url` query."""
    return f"http://{host}:{port}/?url=" + quote(f"rerun+http://{host}:{port + 1}/proxy", safe="")


def _refuse_busy_ports(bind: str, ports: tuple[int, ...]) -> None:
    """Rerun only warns when a port is taken and serves on: the page then shows another server's
    recording, or nothing. Binding first (as Rerun does: address reuse on) tells it in one line."""
    for port in ports:
        with socket.socket(socket.AF_INET6 if ":" in bind else socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind((bind, port))
            except OSError as error:
                raise ViewerError(f"cannot serve on {bind}:{port} ({error.strerror}): "
                                  f"choose other ports with --port (it uses PORT and PORT + 1)") from None


def _wait_until_served(server: subprocess.Popen, url: str, rrd: Path) -> None:
    """Return once the page answers; fail in one line if the server exits first or never answers."""
    deadline = time.monotonic() + SERVER_START_S
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise ViewerError(f"{rrd}: Rerun's web viewer server stopped at start (exit code {server.returncode})")
        try:
            with urllib.request.urlopen(url, timeout=2):
                return
        except (urllib.error.URLError, OSError):
            time.sleep(0.2)
    raise ViewerError(f"{rrd}: Rerun's web viewer server did not answer on {url} within {SERVER_START_S:.0f} s")


def serve_web(rrd: Path, port: int, bind: str) -> None:
    """Serve the web viewer with `rrd` until Ctrl-C (or SIGTERM), then stop the server."""
    _refuse_busy_ports(bind, (port, port + 1))
    everywhere = bind in ("0.0.0.0", "::")
    loopback = bind in ("127.0.0.1", "::1", "localhost")
    # Its own process group: stopping it reaches the Rerun binary behind the Python launcher.
    server = subprocess.Popen(_rerun("--serve-web", str(rrd), "--bind", bind, "--web-viewer-port", str(port),
                                     "--port", str(port + 1)),
                              env=_quiet_env(), stdout=subprocess.DEVNULL, start_new_session=True)
    on_sigterm = signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # `finally` stops the server then
    try:
        _wait_until_served(server, f"http://{'127.0.0.1' if everywhere or loopback else bind}:{port}/", rrd)
        host = socket.gethostname()
        console.print(f"Rerun's web viewer is serving {rrd}; open in a browser:", highlight=False)
        if not loopback:
            console.print(f"  {viewer_url(host if everywhere else bind, port)}", highlight=False, soft_wrap=True)
        console.print(f"  {viewer_url('localhost', port)}", highlight=False, soft_wrap=True)
        console.print(f"from another machine, forward both ports first: ssh -L {port}:localhost:{port} "
                      f"-L {port + 1}:localhost:{port + 1} {host}", highlight=False, soft_wrap=True)
        sys.stdout.flush()
        err_console.print("Ctrl-C stops the server.")
        server.wait()
        raise ViewerError(f"{rrd}: Rerun's web viewer server stopped (exit code {server.returncode})")
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, on_sigterm)
        if server.poll() is None:
            os.killpg(server.pid, signal.SIGTERM)
            try:
                server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(server.pid, signal.SIGKILL)
