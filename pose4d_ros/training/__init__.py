"""The fitting of what core runs: the part model (`dpm`: its training steps, samples, solver and
mining), its frames and calibration (`part_model`), boosted trees (`boost`) and the part
refiner's cascade (`refiner`), and the PyTorch twin of `core.convnet` that trains the
photograph network (`convnet_torch`; needs `make train-env`)."""
