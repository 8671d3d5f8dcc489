"""The progress callbacks of long runs, one signature for each kind of count.

A run calls its callback after each unit of work with (done, total), so that the caller (the CLI's
progress bars, a notebook, a test that interrupts a run) can follow it without the run knowing how
progress is shown.
"""

from __future__ import annotations

from collections.abc import Callable

# (units done, units in all): frames of one recording, frames of a bag, ...
Progress = Callable[[int, int], None]

# (label, units done, units in the labelled part): one run over several parts, e.g. the sessions
# of a detection ("source", "target") or the methods and sessions of an evaluation ("NN source").
LabelledProgress = Callable[[str, int, int], None]
