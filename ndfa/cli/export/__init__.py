"""`ndfa export ...`: ndfa recordings out in other formats, one module per format (`tum`, `bag`)."""

import typer

from ndfa.cli.app import app

export_app = typer.Typer(no_args_is_help=True, help="Write ndfa recordings out in other formats.")
app.add_typer(export_app, name="export")
