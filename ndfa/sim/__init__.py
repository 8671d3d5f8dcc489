"""The synthetic world, without I/O: procedural mugs, room and tables, layouts and changes,
camera routes, raycast renderer and sensor noise."""
