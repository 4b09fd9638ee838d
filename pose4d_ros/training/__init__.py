"""Training around the core's fitting: the part model's frames and calibration (`part_model`),
the part refiner's cascade (`refiner`), and the PyTorch twin of `core.convnet` that trains the
photograph network (`convnet_torch`; needs `make train-env`)."""
