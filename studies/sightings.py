"""Question: do sightings (views too small to encode, `ndfa.change.sightings`) counted toward the
waiting minimum (`WaitingConfig.sightings`) find random 4's mug 11 without costing false reports?
Answer and figures: docs/detector.md, "Sightings" (2026-12-06).

Runs `ndfa detect` exactly as the command line does, with only `WaitingConfig.sightings` set:

    python studies/sightings.py on SRC.mcap TGT.mcap --threads 1 [--frame-step 2] [--poses estimate] --json out.json
"""

from __future__ import annotations

import dataclasses
import sys

import ndfa.cli  # noqa: F401  (registers the commands; first, as `ndfa` does)
import ndfa.cli.detect as detect_command
from ndfa.change.config import DetectorConfig, WaitingConfig
from ndfa.cli.app import main


class _Sightings(DetectorConfig):
    """ndfa's detector defaults but whether sightings count (set below)."""

    sightings = False

    def __new__(cls, *args, **kwargs):  # type: ignore[no-untyped-def]
        config = DetectorConfig(*args, **kwargs)
        return dataclasses.replace(config, waiting=dataclasses.replace(config.waiting, sightings=cls.sightings))


if __name__ == "__main__":
    if sys.argv[1] not in ("on", "off"):
        sys.exit("usage: python studies/sightings.py on|off SRC TGT [ndfa detect options]")
    shipped = WaitingConfig().sightings
    _Sightings.sightings = sys.argv[1] == "on"
    assert _Sightings().waiting.sightings == _Sightings.sightings and isinstance(_Sightings(), DetectorConfig)
    assert WaitingConfig().sightings is shipped  # the shipped default is untouched
    detect_command.DetectorConfig = _Sightings   # type: ignore[misc]
    sys.argv = ["ndfa", "detect"] + sys.argv[2:]
    main()
