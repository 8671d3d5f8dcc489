"""The fuzz suite (issue 18): generated bad input for every command that reads a file, checked
against one property (`property.check_cli`). `pytest -q` runs a short deterministic pass;
`pytest -m fuzz --fuzz-examples N` a long one."""
