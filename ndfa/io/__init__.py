"""Files in and out: atomic writes, the MCAP recording contract, importers and exporters, the
TUM trajectory format (tum_format.py)."""
