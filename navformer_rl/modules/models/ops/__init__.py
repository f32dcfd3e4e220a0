"""CPU training kernels of the model: attention with dropout, dropout,
the last convolution's weight gradient."""
