"""Question: would testing objects from their first measurement (`WaitingConfig.min_measurements` 1
instead of 3) find the seven masked scenes' one miss without costing precision on real data?
Answer and figures: docs/results.md, "The waiting policy on real data" (2026-12-06).

Runs `ndfa detect` exactly as the command line does, with only the waiting policy's minimum changed:

    python studies/waiting_policy.py 1 SRC.mcap TGT.mcap --threads 1 [--frame-step 2] [--poses estimate] --json out.json
"""

from __future__ import annotations

import dataclasses
import sys

import ndfa.cli  # noqa: F401  (registers the commands; first, as `ndfa` does)
import ndfa.cli.detect as detect_command
from ndfa.change.config import DetectorConfig, WaitingConfig
from ndfa.cli.app import main


class _Waiting(DetectorConfig):
    """ndfa's detector defaults but the waiting policy's minimum (set below)."""

    min_measurements = 3

    def __new__(cls, *args, **kwargs):  # type: ignore[no-untyped-def]
        config = DetectorConfig(*args, **kwargs)
        return dataclasses.replace(config, waiting=dataclasses.replace(config.waiting, min_measurements=cls.min_measurements))


if __name__ == "__main__":
    _Waiting.min_measurements = int(sys.argv[1])
    assert _Waiting().waiting.min_measurements == _Waiting.min_measurements and isinstance(_Waiting(), DetectorConfig)
    assert WaitingConfig().min_measurements == 3    # the shipped default is untouched
    detect_command.DetectorConfig = _Waiting        # type: ignore[misc]
    sys.argv = ["ndfa", "detect"] + sys.argv[2:]
    main()
