"""Load the generated evaluators: compiled C (cached by content hash) or CasADi's VM.

Steps, one small class each (PyDy-style): :class:`GeneratedCode` locates ``generated/`` and
refuses stale code; :class:`Compiler` builds the shared library into a cache keyed by the
SHA-256 of the C source, the compiler and its flags (written with ``os.replace``, never in the
source tree, no ``os.chdir``); :class:`Evaluators` loads the functions with ``casadi.external``,
or with ``casadi.Function.load`` on the serialised copies when no C compiler is found (one
warning, never silently).
"""
from __future__ import annotations

import ctypes
import functools
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

__all__ = ["StaleGeneratedCode", "GeneratedCode", "Compiler", "Evaluators", "evaluators"]

_ROOT = Path(__file__).resolve().parents[2]
CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off")


class StaleGeneratedCode(RuntimeError):
    """generated/ does not match its manifest or the symbolic sources."""


class NoCompiler(RuntimeError):
    """No C compiler could be found."""


class GeneratedCode:
    """The checked content of ``generated/`` (default: next to ``src/``; env HAA_SYM_GENERATED)."""

    def __init__(self, directory: str | Path | None = None, root: Path = _ROOT):
        self.dir = Path(directory or os.environ.get("HAA_SYM_GENERATED") or root / "generated")
        self.root = root
        man = self.dir / "MANIFEST.json"
        if not man.is_file():
            raise StaleGeneratedCode(f"{man} is missing: run `make derive`")
        self.manifest = json.loads(man.read_text())
        self.check()

    def check(self) -> None:
        for name, digest in self.manifest["files"].items():
            path = self.dir / name
            if not path.is_file() or hashlib.sha256(path.read_bytes()).hexdigest() != digest:
                raise StaleGeneratedCode(
                    f"{path} does not match generated/MANIFEST.json: run `make derive`")
        # In a source tree, the symbolic sources must be the ones the code was generated from.
        sources = [self.root / rel for rel in self.manifest["sources"]]
        if all(p.is_file() for p in sources):
            h = hashlib.sha256()
            for rel, p in zip(self.manifest["sources"], sources):
                h.update(rel.encode() + b"\0" + p.read_bytes() + b"\0")
            if h.hexdigest() != self.manifest["source_sha256"]:
                raise StaleGeneratedCode(
                    "the symbolic model or code generator changed since generated/ was written: "
                    "run `make derive`")
        if self.manifest["tools"]["casadi"] != ca.__version__:
            raise StaleGeneratedCode(
                f"generated/ was written by casadi {self.manifest['tools']['casadi']}, this is "
                f"casadi {ca.__version__}: install the pinned version (`make venv`) or run `make derive`")

    @property
    def c_file(self) -> Path:
        return self.dir / f"{self.manifest['library']}.c"

    @property
    def function_names(self) -> list[str]:
        return list(self.manifest["functions"])


class Compiler:
    """Compile one C file into a shared library cached by content hash."""

    def __init__(self, cc: str | None = None, cache_dir: str | Path | None = None):
        self.cc = cc or os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") \
            or shutil.which("clang")
        if not self.cc or not shutil.which(self.cc):
            raise NoCompiler("no C compiler found (set CC or install gcc)")
        self.cache = Path(cache_dir or os.environ.get("HAA_SYM_CACHE")
                          or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "haa_sym")

    def _version(self) -> str:
        out = subprocess.run([self.cc, "--version"], capture_output=True, text=True)
        return out.stdout.splitlines()[0] if out.stdout else self.cc

    def build(self, c_file: Path) -> Path:
        src = c_file.read_bytes()
        key = hashlib.sha256(src + "\0".join((self._version(),) + CFLAGS).encode()).hexdigest()[:24]
        target = self.cache / key / (c_file.stem + ".so")
        if target.is_file():
            return target
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".so")
        os.close(fd)
        proc = subprocess.run([self.cc, *CFLAGS, str(c_file), "-o", tmp, "-lm"],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            os.unlink(tmp)
            raise RuntimeError(f"compiling {c_file} with {self.cc} failed:\n{proc.stderr}")
        os.replace(tmp, target)
        return target


class Evaluators:
    """The generated CasADi Functions, by name: ``ev["haa_decide16"]``.

    Parameters
    ----------
    backend : {"auto", "compiled", "vm"}
        "compiled" requires a C compiler; "vm" evaluates the serialised Functions in CasADi's
        virtual machine; "auto" compiles when it can and otherwise warns once and uses the VM.
    """

    def __init__(self, backend: str = "auto", code: GeneratedCode | None = None,
                 compiler: Compiler | None = None):
        if backend not in ("auto", "compiled", "vm"):
            raise ValueError(f"backend = {backend!r}; allowed: 'auto', 'compiled', 'vm'")
        self.code = code or GeneratedCode()
        self._fns: dict[str, ca.Function] = {}
        if backend in ("auto", "compiled"):
            try:
                comp = compiler or Compiler()
            except NoCompiler as exc:
                if backend == "compiled":
                    raise
                warnings.warn(f"haa_sym: {exc}; evaluating the generated CasADi functions in "
                              "CasADi's virtual machine (slower, same numbers)", RuntimeWarning,
                              stacklevel=2)
                backend = "vm"
            else:
                self.library = comp.build(self.code.c_file)
                backend = "compiled"
        self.backend = backend

    def __getitem__(self, name: str) -> ca.Function:
        if name not in self._fns:
            if name not in self.code.function_names:
                raise KeyError(f"no generated function {name!r}; have {self.code.function_names}")
            if self.backend == "compiled":
                self._fns[name] = ca.external(name, str(self.library))
            else:
                self._fns[name] = ca.Function.deserialize(
                    (self.code.dir / f"{name}.casadi").read_text())
        return self._fns[name]

    def call_columns(self, name: str, args: list, col: int) -> list[np.ndarray]:
        """Evaluate ``name`` on every column of ``args[col]``, the other inputs shared.

        Compiled: one call of the generated column driver (``codegen/driver.c``) for all
        columns. VM: CasADi's own column mapping. Returns each output as (n_columns, size).
        """
        f = self[name]
        cols = np.asfortranarray(np.atleast_2d(np.asarray(args[col], dtype=float)))
        n = cols.shape[1]
        if cols.shape[0] != f.size1_in(col):
            raise ValueError(f"{name}: input {col} has {cols.shape[0]} rows, expected {f.size1_in(col)}")
        shared = []
        for i, a in enumerate(args):
            if i == col:
                shared.append(cols)
                continue
            a = np.asfortranarray(np.asarray(a, dtype=float))
            if a.size != f.numel_in(i):
                raise ValueError(f"{name}: input {i} has {a.size} values, expected {f.numel_in(i)}")
            shared.append(a)
        sizes = [f.numel_out(j) for j in range(f.n_out())]
        if self.backend != "compiled" or n == 0:
            res = f(*shared)
            res = res if isinstance(res, (list, tuple)) else [res]
            return [np.array(r).reshape(sizes[j], n, order="F").T for j, r in enumerate(res)]
        lib = self._cdll()
        outs = [np.empty((n, sz)) for sz in sizes]
        dbl = ctypes.POINTER(ctypes.c_double)
        arg_ptrs = (dbl * len(shared))(*[a.ctypes.data_as(dbl) for a in shared])
        out_ptrs = (dbl * len(outs))(*[o.ctypes.data_as(dbl) for o in outs])
        strides = (ctypes.c_longlong * len(outs))(*sizes)
        flag = lib.haa_columns(ctypes.cast(getattr(lib, name), ctypes.c_void_p),
                               ctypes.cast(getattr(lib, f"{name}_work"), ctypes.c_void_p),
                               len(shared), arg_ptrs, col, cols.shape[0], n, len(outs), out_ptrs,
                               strides)
        if flag:
            raise RuntimeError(f"generated {name} failed on a column (code {flag})")
        return outs

    def _cdll(self):
        if getattr(self, "_lib", None) is None:
            lib = ctypes.CDLL(str(self.library))
            lib.haa_columns.restype = ctypes.c_int
            lib.haa_columns.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong,
                                        ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong,
                                        ctypes.c_longlong, ctypes.c_longlong, ctypes.c_void_p,
                                        ctypes.c_void_p]
            self._lib = lib
        return self._lib

    @property
    def capacities(self) -> list[int]:
        return list(self.code.manifest["capacities"])


@functools.lru_cache(maxsize=None)
def evaluators(backend: str = "auto") -> Evaluators:
    """The process-wide :class:`Evaluators` for ``backend`` (compiled once, then cached)."""
    return Evaluators(backend)
