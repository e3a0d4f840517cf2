"""The sampled closed loop (layer 5): options, the velocity-filter registry, the controller's
elements, the exact characteristic-polynomial basis, the plant, the loop and its state space."""
