"""Training the NDF: per-mug samples (`mug_samples`), rendered views (`views`), datasets
(`dataset`), batches (`batches`), shape parameters (`shape_parameters`), losses, metrics, the
training loop (`train`), validation (`validate`), checkpoints (`checkpoint`) and ndf-eval."""
