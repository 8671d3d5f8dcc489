"""Importers: each turns one kind of input into recordings that follow `ndfa.recording`."""
