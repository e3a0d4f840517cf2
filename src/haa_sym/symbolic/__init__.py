"""Symbolic derivations (sympy). Imported by ``haa_sym.check.verify`` and ``codegen/``, never by the
numeric runtime."""
