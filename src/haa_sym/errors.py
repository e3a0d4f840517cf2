"""The library's error for bad input, in a module of its own so that every module can raise it
without importing :mod:`haa_sym.params` (which imports the actuators and the velocity-filter
registry, :mod:`haa_sym.filters`). ``haa_sym.params.ParameterError`` and
``haa_sym.ParameterError`` are this class."""
from __future__ import annotations

__all__ = ["ParameterError"]


class ParameterError(ValueError):
    """A parameter is missing, unknown or outside what the physics allows."""
