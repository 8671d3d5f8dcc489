# The two commands of the README, and the developer's quick loop. Each sets everything up first
# (scripts/setup.sh is idempotent: pip runs only when pyproject.toml changed since the last install).
VENV ?= .venv
DEMO_OUT ?= out/demo

.PHONY: setup demo test check lint
setup:
	bash scripts/setup.sh

# The main job on the shipped default: detect the changes between the sample recordings
# (recordings/sample, synthetic), with every intermediate logged to Rerun and to Polars tables.
demo: setup
	$(VENV)/bin/ndfa detect recordings/sample/source.mcap recordings/sample/target.mcap \
		--log $(DEMO_OUT).rrd --tables $(DEMO_OUT)-tables --json $(DEMO_OUT).json

# Layering (import-linter: the core imports no I/O), lint (ruff) and types (mypy, strict on the core).
lint: setup
	$(VENV)/bin/lint-imports
	$(VENV)/bin/ruff check ndfa tests scripts studies
	$(VENV)/bin/mypy

test: setup lint
	$(VENV)/bin/python -m pytest -q

# The quick loop: lint and the tests not marked slow (`@pytest.mark.slow`: end-to-end runs, training,
# notebooks, the viewer and the cluster). `make test` runs them all, as CI does.
check: setup lint
	$(VENV)/bin/python -m pytest -q -m "not slow"
