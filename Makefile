# The two commands of the README. Both set everything up first (scripts/setup.sh is idempotent).
VENV ?= .venv
DEMO_OUT ?= out/paper

.PHONY: setup demo test
setup:
	bash scripts/setup.sh

# The main job on the shipped default: render the paper's synthetic scene pair and summarise it.
demo: setup
	$(VENV)/bin/ndfa ingest sim --preset paper --seed 0 --out $(DEMO_OUT)
	$(VENV)/bin/ndfa info $(DEMO_OUT)/target.mcap

test: setup
	$(VENV)/bin/python -m pytest -q
