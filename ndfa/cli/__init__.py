"""The `ndfa` command. Each subcommand parses its options, calls one library function and prints
a short table; any `NdfaError` becomes a one-line message and exit code 2.

One module per command group registers its commands on the shared app (`app.py`); importing them
here, in the order `ndfa --help` lists them, is what registers them.
"""

# isort: off
from ndfa.cli import environment  # noqa: F401  (first: before anything imports torch)
from ndfa.cli import ingest  # noqa: F401
from ndfa.cli import ndf  # noqa: F401
from ndfa.cli import detect  # noqa: F401
from ndfa.cli import plant  # noqa: F401
from ndfa.cli import view  # noqa: F401
from ndfa.cli import bench  # noqa: F401
# isort: on
from ndfa.cli.app import app, main

__all__ = ["app", "main"]
