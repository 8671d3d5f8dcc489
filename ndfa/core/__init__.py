"""The facts every stage shares: frames, geometry, events, errors and conventions. Pure: no I/O."""
