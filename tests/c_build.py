"""Compiling the C that haa_sym writes (the schedule's lookup, the ros2 region test) into a shared
library for a test: one set of strict flags, the evaluators' compiler, a skip without one."""
from __future__ import annotations

import ctypes
import subprocess
from pathlib import Path

import pytest

from haa_sym.compiled.generated import Compiler
from haa_sym.errors import NoCompiler

#: C99 with every warning an error, and no fused multiply-add contraction (the C must give the
#: Python lookup's bits)
STRICT = ("-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-Wconversion", "-Wshadow",
          "-Wdouble-promotion", "-Wstrict-prototypes", "-Wmissing-prototypes", "-Wfloat-equal",
          "-Wvla", "-ffp-contract=off")


def compiler() -> list[str]:
    """The evaluators' compiler (CC, else cc/gcc/clang); the test is skipped without one."""
    try:
        return Compiler().argv
    except NoCompiler as exc:
        pytest.skip(str(exc))


def shared_library(source: Path, lib: Path, extra=()) -> ctypes.CDLL:
    """``source`` compiled with :data:`STRICT` and -O2 into the shared library ``lib``, loaded."""
    proc = subprocess.run([*compiler(), *STRICT, "-O2", *extra, str(source), "-fPIC", "-shared", "-o", str(lib),
                           "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return ctypes.CDLL(str(lib))
