"""Analyses of a closed loop (layer 6): margins (one phase-margin rule), passivity, the torque
loop, contact stiffness, region maps, robust regions, and the exact boundaries (`boundaries/`)."""
