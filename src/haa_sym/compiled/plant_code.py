"""The plant function of an actuator: generated (built-in) or compiled on first use.

An actuator is a :class:`~haa_sym.model.actuator.Topology` (a chain, from a file or code) or a
:class:`~haa_sym.symbolic.model.LinearActuatorModel` (a sympy model written in code); both reach
the code generator as the latter (``haa_sym.symbolic.chain.symbolic_model(actuator)``). A built-in actuator's topology
(``model/*.toml``) has its function in ``generated/`` (listed under its fingerprint in
``MANIFEST.json``); it is loaded with the other generated evaluators and needs no sympy. Any
other actuator is compiled once: CasADi writes the C of its model into the content-hash cache
(``HAA_SYM_CACHE``, default ``~/.cache/haa_sym``) under a key of its fingerprint (a topology's
structure, a model's content: ``srepr`` of A, B, C, VC0 and the names), the code generator's
sources and the CasADi version (sympy runs only when that entry is absent), and :class:`haa_sym.compiled.generated.Compiler` builds
and verifies the shared library; without a C compiler the serialised function runs in CasADi's
virtual machine (one warning). The generated C and ``.casadi`` files are checked against their
recorded SHA-256 before every use and regenerated when damaged. ``haa-sym compile FILE`` does
this ahead of time.
"""
from __future__ import annotations

import functools
import hashlib
import os
import tempfile
import warnings
from pathlib import Path

import casadi as ca

from haa_sym.model.actuator import Actuator, Topology
from haa_sym.errors import CompilerError, NoCompiler
from haa_sym.compiled.generated import Compiler, _read_regular, _sha256, default_cache_dir, evaluators
from haa_sym.io.progress import message

__all__ = ["plant_function", "compile_actuator", "compile_topology", "CompiledTopology"]

# The files that define a compiled actuator's code (besides its fingerprint and CasADi's version).
_CODE_SOURCES = ("model/actuator.py", "symbolic/chain.py", "symbolic/model.py", "symbolic/symbolic_to_casadi.py")


class CompiledTopology:
    """Where a user actuator's code lives: ``c_file``, ``casadi_file`` and, when compiled,
    ``library``; ``backend`` is "compiled" or "vm"."""

    def __init__(self, topology: Actuator, c_file: Path, casadi_file: Path, library: Path | None):
        self.topology, self.c_file, self.casadi_file, self.library = topology, c_file, casadi_file, library
        self.backend = "compiled" if library is not None else "vm"

    def function(self) -> ca.Function:
        name = self.topology.function_name
        if self.library is not None:
            return ca.external(name, str(self.library))
        if not _verified(self.casadi_file):
            # damaged since it was generated (a disk fault, an edit): derived again, as a damaged
            # library is rebuilt, rather than handed to CasADi's parser
            _generate(self.topology, self.casadi_file.parent, quiet=True)
        return ca.Function.deserialize(self.casadi_file.read_text())


def _code_key(topology: Actuator) -> str:
    pkg = Path(__file__).resolve().parents[1]           # haa_sym/compiled/plant_code.py
    h = hashlib.sha256(topology.fingerprint.encode() + b"\0" + ca.__version__.encode() + b"\0")
    for rel in _CODE_SOURCES:
        h.update(rel.encode() + b"\0" + (pkg / rel).read_bytes() + b"\0")
    return h.hexdigest()[:24]


def _verified(path: Path) -> bool:
    try:
        return _sha256(path) == _read_regular(path.with_name(path.name + ".sha256"), 4096).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        return False


def _write_verified(path: Path, data: bytes) -> None:
    """Write ``data`` and its SHA-256 beside it, each by rename (never a partial file)."""
    for target, content in ((path, data),
                            (path.with_name(path.name + ".sha256"),
                             (hashlib.sha256(data).hexdigest() + "\n").encode())):
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=target.name + ".")
        with os.fdopen(fd, "wb") as fh:
            fh.write(content)
        os.replace(tmp, target)


def _generate(topology: Actuator, directory: Path, quiet: bool) -> tuple[Path, Path]:
    """The actuator's C and serialised function in ``directory`` (sympy only when absent)."""
    name = topology.function_name
    c_file, cas_file = directory / f"{name}.c", directory / f"{name}.casadi"
    if _verified(c_file) and _verified(cas_file):
        return c_file, cas_file
    if not quiet:                                   # silenced by --quiet (set_progress(False))
        message(f"haa_sym: compiling the plant of {topology.source} ({_kind(topology)} "
                f"{topology.fingerprint[:12]}: {topology.describe()}) into {directory}; once per "
                f"{_kind(topology)}")
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CompilerError(
            f"the compiled-code cache {directory.parent.parent} (HAA_SYM_CACHE, default "
            f"~/.cache/haa_sym) cannot be created: {exc.strerror or exc}; allowed: a writable "
            "directory") from None
    # sympy: the compile step of a new actuator only, never the numeric runtime
    from haa_sym.symbolic.chain import symbolic_model
    from haa_sym.symbolic.symbolic_to_casadi import plant_function as derive
    f = derive(symbolic_model(topology), name)
    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        cg = ca.CodeGenerator(f"{name}.c", {"with_header": False})
        cg.add(f)
        cg.generate(tmp + os.sep)
        c_src = Path(tmp, f"{name}.c").read_bytes()
    _write_verified(c_file, c_src)
    _write_verified(cas_file, f.serialize().encode())
    return c_file, cas_file


def _kind(actuator: Actuator) -> str:
    return "topology" if isinstance(actuator, Topology) else "model"


def compile_actuator(topology: Actuator, backend: str = "auto", *, cache_dir: str | Path | None = None,
                     compiler: Compiler | None = None, quiet: bool = False) -> CompiledTopology:
    """Generate (sympy, once) and compile (C, once) the plant function of an actuator.

    Parameters
    ----------
    topology : Topology or LinearActuatorModel
        The actuator (a chain, or a sympy model written in code).
    backend : {"auto", "compiled", "vm"}
        "compiled" requires a C compiler; "auto" warns once and uses the VM without one.
    cache_dir : str or Path, optional
        Default env ``HAA_SYM_CACHE``, else ``~/.cache/haa_sym``.
    quiet : bool
        No progress line on stderr.

    Raises
    ------
    CompilerError
        The cache is not writable, or the C compiler failed (its output in the message).
    """
    if backend not in ("auto", "compiled", "vm"):
        raise ValueError(f"backend = {backend!r}; allowed: 'auto', 'compiled', 'vm'")
    root = Path(cache_dir) if cache_dir is not None else (compiler.cache if compiler else default_cache_dir())
    directory = root / "topologies" / _code_key(topology)
    c_file, cas_file = _generate(topology, directory, quiet)
    library = None
    if backend in ("auto", "compiled"):
        try:
            comp = compiler or Compiler(cache_dir=root)
        except NoCompiler as exc:
            if backend == "compiled":
                raise
            warnings.warn(f"haa_sym: {exc}; evaluating the plant of {topology.source} in CasADi's "
                          "virtual machine (slower, same numbers)", RuntimeWarning, stacklevel=2)
        else:
            library = comp.build(c_file, (topology.function_name,))
    return CompiledTopology(topology, c_file, cas_file, library)


compile_topology = compile_actuator        # the name of the first API (topologies only)


@functools.lru_cache(maxsize=None)
def _user_function(topology: Actuator, backend: str) -> ca.Function:
    return compile_actuator(topology, backend).function()


def plant_function(topology: Actuator, backend: str = "auto") -> ca.Function:
    """``f(p) -> (A, B, C, VC0)`` of an actuator, ``p`` in ``topology.parameter_keys`` order:
    the generated function of a built-in topology, else compiled on first use (cached)."""
    ev = evaluators(backend)
    entry = ev.code.manifest["topologies"].get(topology.fingerprint)
    if entry is not None:
        return ev[entry["function"]]
    return _user_function(topology, ev.backend)
