"""Build-time code generation: symbolic model (sympy) -> CasADi Functions -> C in ``generated/``.

Run ``make derive`` (``python -m codegen.generate``). The numeric runtime never imports this.
"""
