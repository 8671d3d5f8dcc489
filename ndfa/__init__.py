"""ndfa: robust object-level change detection with Neural Descriptor Fields."""
__version__ = "0.1.0"
