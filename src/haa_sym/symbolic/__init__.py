"""Symbolic derivations (sympy). Imported by ``haa_sym.verify`` and ``codegen/``, never by the
numeric runtime."""
