"""Sinks: turn the pipeline's events (`ndfa.core.events`) into a Rerun recording or Polars tables."""
