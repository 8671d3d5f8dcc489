"""`ndfa ingest ...`: turn a data source into ndfa recordings. One module per source (`sim`, `tum`,
`bag`), registering its command on `ingest_app`; `estimated_poses` holds what the importers share
for `--poses estimate`."""

from ndfa.cli.app import app, typer_app

ingest_app = typer_app(no_args_is_help=True, help="Turn a data source into ndfa recordings (MCAP).")
app.add_typer(ingest_app, name="ingest")
