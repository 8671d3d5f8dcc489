"""`ndfa export ...`: ndfa recordings out in other formats, one module per format (`tum`, `bag`)."""

from ndfa.cli.app import app, typer_app

export_app = typer_app(no_args_is_help=True, help="Write ndfa recordings out in other formats.")
app.add_typer(export_app, name="export")
