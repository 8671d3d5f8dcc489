"""Neural Descriptor Fields, model and inference only: vector-neuron layers (`vn`), the model's
options (`config`), its encoder network (`encoder_net`), occupancy decoder (`decoder`), code and
center heads (`heads`), the assembled model (`model`), reading checkpoints (`checkpoint`) and
inference on observations (`encoder`)."""
