"""Identification of an actuator's parameters from logged experiments (docs/identify.md): the
model with exact derivatives and its fast simulation (model), the torque loop closed around it
(closed), the output-error fit and its confidence intervals (identify) and the fitted parameter
file (fitted_file). Above analysis/ (it fits model/ values through compiled/ functions), below
design/."""
