"""Scoring against ground truth, the paper's baselines, Table I, sweeps and benchmarks."""
