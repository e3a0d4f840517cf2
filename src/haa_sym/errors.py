"""Every exception type of haa_sym (the bottom layer: every other module may import it).

The command line turns a :class:`ParameterError` (and so an :class:`OutputError`) into exit
status 2 with its message, which names the field, the value and what is allowed;
:class:`StaleGeneratedCode` and :class:`CompilerError` say what to run.
"""

__all__ = ["ParameterError", "OutputError", "StaleGeneratedCode", "CompilerError", "NoCompiler", "Terminated"]


class ParameterError(ValueError):
    """A parameter is missing, unknown or outside what the physics allows."""


class OutputError(ParameterError):
    """An output cannot be written where the user asked (message names the user's path)."""


class StaleGeneratedCode(RuntimeError):
    """generated/ is missing, damaged, or does not match its manifest or the symbolic sources."""


class CompilerError(RuntimeError):
    """The C compiler could not build the generated code."""


class NoCompiler(CompilerError):
    """No C compiler could be found."""


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM (``kill``, a job scheduler's time limit). Raised by the
    command line's handler so that it unwinds like Ctrl-C (SIGINT): every staged output is
    rolled back (:mod:`haa_sym.io.outputs`) and the command exits with 128 + 15 = 143."""
