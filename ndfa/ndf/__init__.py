"""Neural Descriptor Fields: SO(3)-equivariant vector-neuron layers (`vn`) and the NDF model (`model`)."""
