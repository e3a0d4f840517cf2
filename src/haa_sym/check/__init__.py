"""Independent checks (layer 8): the reference closed loop built with its own algebra, the
symbolic verification of the paper's equations, the eigenvalue cross-check of maps."""
