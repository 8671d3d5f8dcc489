"""Training the NDF: rendered views, datasets, losses, the training loop and ndf-eval."""
