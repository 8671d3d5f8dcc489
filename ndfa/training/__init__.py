"""Training the NDF: per-object samples (`object_samples`), rendered views (`views`), datasets
(`dataset`), batches (`batches`), shape parameters (`shape_parameters`), losses, metrics, the
training loop (`train`; its settings `train_config`, what it fits `trained_parts`), validation
(`validate`), checkpoints (`checkpoint`) and ndf-eval."""
