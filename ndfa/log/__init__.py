"""Sinks: turn the pipeline's events (`ndfa.events`) into a Rerun recording or Polars tables."""
