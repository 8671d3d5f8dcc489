"""The `ndfa` command. Each subcommand parses its options, calls one library function and prints
a short table; any `NdfaError` becomes a one-line message and exit code 2.

One module per command (`detect.py` is `ndfa detect`, `ingest/tum.py` is `ndfa ingest tum`)
registers it on the shared app (`app.py`) or its group's; importing them here, in the order
`ndfa --help` lists them (the groups, `ingest` and `export`, come after the commands), is what
registers them.
"""

# isort: off
from ndfa.cli import environment  # noqa: F401  (first: before anything imports torch)
from ndfa.cli import info  # noqa: F401
from ndfa.cli import train, ndf_export, ndf_eval  # noqa: F401
from ndfa.cli import detect, segment, eval, poses  # noqa: F401
from ndfa.cli import plant  # noqa: F401
from ndfa.cli import view  # noqa: F401
from ndfa.cli import bench  # noqa: F401
from ndfa.cli.ingest import sim, tum, bag  # noqa: F401
from ndfa.cli.export import tum as export_tum, bag as export_bag  # noqa: F401
# isort: on
from ndfa.cli.app import app, main

__all__ = ["app", "main"]
