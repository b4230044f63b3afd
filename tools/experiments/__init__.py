"""Long experiments on the emulator: the paper's segmentation experiments and the soak."""
