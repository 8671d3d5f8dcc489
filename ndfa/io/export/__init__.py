"""Exporters: each writes an ndfa recording out in another format, for other tools (and round trips)."""
