"""I/O shells around the pure pipeline: detect, replay, segment."""
