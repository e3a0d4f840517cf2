"""Design outputs for a joint's controller: the C templates of the torque-gain schedule (``templates/``)."""
