"""The Typer app every `ndfa` subcommand registers on, the consoles they print to, and `main`."""

from __future__ import annotations

import functools
import sys
import warnings
from collections.abc import Callable
from typing import Any

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from typer.core import TyperGroup

from ndfa.cli.checks import command_outputs, refuse_outputs_among_inputs
from ndfa.core.errors import NdfaError
from ndfa.core.progress import LabelledProgress
from ndfa.io.atomic import all_or_nothing


class CommandGroup(TyperGroup):
    """`ndfa` and its groups (`ingest`, `export`). A command runs inside one `all_or_nothing` block:
    its outputs stay only when it succeeds, each one as it was otherwise (`ndfa.io.atomic`); and
    once its options are parsed, an output that is one of its inputs is refused before any work."""

    def __init__(self, **attrs: Any) -> None:
        super().__init__(**attrs)
        for command in self.commands.values():
            if not isinstance(command, TyperGroup) and command.callback is not None:
                command.callback = _checked(command.callback)

    def invoke(self, ctx: typer.Context) -> Any:
        if ctx.parent is not None:  # a group inside `ndfa`: the outer invoke holds the block
            return super().invoke(ctx)
        with command_outputs(), all_or_nothing():
            return super().invoke(ctx)


def _checked(callback: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(callback)
    def run(**params: Any) -> Any:
        refuse_outputs_among_inputs(params)
        return callback(**params)

    return run


def typer_app(**settings: Any) -> typer.Typer:
    """A Typer app (or group) whose commands run as `CommandGroup` says."""
    return typer.Typer(cls=CommandGroup, **settings)


app = typer_app(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                help="Robust object-level change detection in RGB-D data with Neural Descriptor Fields.")
console = Console()
err_console = Console(stderr=True)  # progress and messages, so that stdout holds only results


def progress_bar(transient: bool = True) -> Progress:
    """The progress bar of long commands: description, bar, done/total, time left (on stderr)."""
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeRemainingColumn(), console=err_console, transient=transient)


def bar_per_label(progress: Progress, prefix: str = "") -> LabelledProgress:
    """A progress callback that shows one bar on `progress` per label (a session, "NN source", ...)."""
    tasks: dict[str, int] = {}

    def on_progress(label: str, done: int, total: int) -> None:
        if label not in tasks:
            tasks[label] = progress.add_task(prefix + label, total=total)
        progress.update(tasks[label], completed=done)

    return on_progress


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
    """ndfa's own warnings (about a user's input) as one line on stderr, like its errors."""
    if category.__module__.startswith("ndfa."):
        err_console.print(f"[yellow]warning:[/yellow] {message}", highlight=False, soft_wrap=True)
    else:
        _python_show_warning(message, category, filename, lineno, file, line)


_python_show_warning = warnings.showwarning


def main() -> None:
    """Entry point: run the app, turning ndfa's own errors into one line on stderr (and its warnings)."""
    warnings.showwarning = _show_warning
    try:
        app(standalone_mode=False)
    except NdfaError as error:
        err_console.print(f"[red]error:[/red] {error}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except typer.Abort:
        err_console.print("aborted")
        sys.exit(130)
    except Exception as error:  # usage errors arrive here in non-standalone mode
        # typer >= 0.29 vendors its own click (typer.BadParameter is not a click.ClickException):
        # recognise both by what they can do.
        if callable(getattr(error, "format_message", None)) and isinstance(getattr(error, "exit_code", None), int):
            # One line, like ndfa's own errors, with where to read more instead of the usage block.
            context = getattr(error, "ctx", None)
            hint = f" (see '{context.command_path} --help')" if getattr(context, "command_path", None) else ""
            err_console.print(f"[red]error:[/red] {error.format_message()}{hint}", highlight=False, soft_wrap=True)
            sys.exit(error.exit_code)
        raise

