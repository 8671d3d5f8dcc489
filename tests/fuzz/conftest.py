"""Settings of the fuzz tests: a short derandomized pass by default (the same inputs every run, so
CI is deterministic), `--fuzz-examples N` random inputs per generator for the long pass."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, settings

# Examples per generator in the short pass: with the corpus replayed, the whole short pass stays
# well under a minute on 2 cores.
SHORT_EXAMPLES = 25


def pytest_terminal_summary(terminalreporter) -> None:
    """How many generated inputs went through the property, by command (the long pass's count)."""
    from tests.fuzz.property import CHECKED

    if CHECKED:
        by_command = ", ".join(f"{command} {count}" for command, count in sorted(CHECKED.items()))
        terminalreporter.write_line(f"fuzz: {sum(CHECKED.values())} inputs checked ({by_command})")


@pytest.fixture
def fuzz_settings(request) -> settings:
    """What a fuzz test's inner @given function is decorated with. `fuzz_settings(scale)` in a
    test would be nicer, but the number of examples must come from the command line."""
    examples = request.config.getoption("--fuzz-examples")
    return settings(
        max_examples=examples or SHORT_EXAMPLES,
        derandomize=examples is None,
        database=None if examples is None else settings.default.database,
        deadline=None,  # the property enforces its own deadline per input (CPU and wall time)
        suppress_health_check=list(HealthCheck),
        print_blob=True,
    )
