"""Design on top of the analyses (layer 7): the torque-gain scheduler and its table as embedded C."""
