"""Actuators and parameters as data (layer 1): actuator files and their topology, validated
plant and controller parameters, where the bundled files are. No sympy, no CasADi."""
