"""Load the generated evaluators: compiled C (cached by content hash) or CasADi's VM.

Steps, one small class each (PyDy-style): :class:`GeneratedCode` locates ``generated/`` (the
source tree's, or the copy an installed package carries; see :mod:`haa_sym.model.resources`) and
refuses stale, damaged or unreadable code; :class:`Compiler` builds the shared library into a
cache keyed by the SHA-256 of the C source, the compiler command and its flags (written with
``os.replace``, never in the source tree, no ``os.chdir``), records the library's own SHA-256
beside it and checks it before every use, so a truncated or altered library is rebuilt instead
of crashing the process or changing results; :class:`Evaluators` loads the functions with
``casadi.external``, or with ``casadi.Function.load`` on the serialised copies when no C
compiler is found (one warning, never silently).
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import json
import os
import shlex
import shutil
import signal
import stat
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

from haa_sym.errors import CompilerError, NoCompiler, ParameterError, StaleGeneratedCode
from haa_sym.model.params import builtin_actuators, load_params
from haa_sym.model.resources import data_dir, remedy, source_root

__all__ = ["StaleGeneratedCode", "CompilerError", "NoCompiler", "GeneratedCode", "Compiler",
           "Evaluators", "evaluators", "default_cache_dir"]

CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off")
# Manifest keys and their JSON types, as codegen/generate.py writes them.
_MANIFEST_KEYS = {"capacities": list, "files": dict, "functions": list, "library": str,
                  "source_sha256": str, "sources": list, "tools": dict, "topologies": dict}
_DEFAULT = object()



def default_cache_dir() -> Path:
    """env ``HAA_SYM_CACHE``, else ``$XDG_CACHE_HOME/haa_sym`` (``~/.cache/haa_sym``)."""
    return Path(os.environ.get("HAA_SYM_CACHE")
                or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "haa_sym")


def _read_regular(path: str | Path, limit: int | None = None) -> bytes:
    """The bytes of the regular file ``path`` (at most ``limit``); OSError for anything else.

    The cache is ours, but what lies in it may not be: a FIFO in a library's place blocked the
    process for ever, a directory or a device must not be read either. Opened without blocking
    and checked before a byte is read."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(f"{path}: not a regular file")
        os.set_blocking(fd, True)
        with os.fdopen(os.dup(fd), "rb") as f:
            return f.read() if limit is None else f.read(limit)
    finally:
        os.close(fd)


def _sha256(path: str | Path) -> str:
    return hashlib.sha256(_read_regular(path)).hexdigest()


def _clear_odd(path: Path) -> None:
    """Remove what stands at ``path`` in our cache if it is not a regular file (a directory, a
    FIFO, a socket): the next write renames a regular file there."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return
    if stat.S_ISDIR(mode):
        shutil.rmtree(path, ignore_errors=True)
    elif not stat.S_ISREG(mode):
        with contextlib.suppress(OSError):
            os.unlink(path)


class GeneratedCode:
    """The checked content of ``generated/``.

    Parameters
    ----------
    directory : str or Path, optional
        Default: env ``HAA_SYM_GENERATED``, else ``generated/`` of the source tree or the
        installed package.
    root : Path or None, optional
        Root of the source tree whose symbolic sources the code must match; default the tree
        this package was loaded from, None for an installed package (whose sources are absent).
    """

    def __init__(self, directory: str | Path | None = None, root: Path | None = _DEFAULT):
        self.dir = Path(directory or os.environ.get("HAA_SYM_GENERATED") or data_dir("generated"))
        self.root = source_root() if root is _DEFAULT else root
        self.manifest = self._read_manifest(self.dir / "MANIFEST.json")
        self.check()

    def _fix(self) -> str:
        if self.root is not None:
            return "run `make derive`"
        if self.dir.resolve() != data_dir("generated").resolve():
            return "regenerate it in a source tree (`make derive`) or unset HAA_SYM_GENERATED"
        return remedy()

    def _read_manifest(self, man: Path) -> dict:
        if not man.is_file():
            raise StaleGeneratedCode(f"{man} is missing: {self._fix()}")
        try:
            m = json.loads(man.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise StaleGeneratedCode(f"{man} is unreadable ({exc}): {self._fix()}") from None
        bad = [k for k, t in _MANIFEST_KEYS.items()
               if not isinstance(m, dict) or not isinstance(m.get(k), t)]
        if not bad:
            # Every file the runtime reads must be covered by a digest.
            needed = [f"{m['library']}.c"] + [f"{fn}.casadi" for fn in m["functions"]]
            bad += [f"files[{n!r}]" for n in needed if not isinstance(m["files"].get(n), str)]
            bad += [] if all(isinstance(r, str) for r in m["sources"]) else ["sources"]
            bad += [] if isinstance(m["tools"].get("casadi"), str) else ["tools.casadi"]
            bad += [] if all(type(c) is int and c > 0 for c in m["capacities"]) else ["capacities"]
            bad += [f"topologies[{fp!r}]" for fp, t in m["topologies"].items()
                    if not (isinstance(t, dict) and t.get("function") in m["functions"]
                            and isinstance(t.get("actuators"), list))]
        if bad:
            raise StaleGeneratedCode(
                f"{man} is invalid (missing or malformed: {', '.join(bad)}): {self._fix()}")
        return m

    def check(self) -> None:
        for name, digest in self.manifest["files"].items():
            path = self.dir / name
            if not path.is_file() or _sha256(path) != digest:
                raise StaleGeneratedCode(
                    f"{path} does not match {self.dir / 'MANIFEST.json'}: {self._fix()}")
        # In a source tree, the symbolic sources must be the ones the code was generated from;
        # an installed package legitimately carries none of them.
        if self.root is not None:
            h = hashlib.sha256()
            for rel in self.manifest["sources"]:
                p = self.root / rel
                if not p.is_file():
                    raise StaleGeneratedCode(
                        f"{p}, a source of generated/ (MANIFEST.json), is missing: run `make derive`")
                h.update(rel.encode() + b"\0" + p.read_bytes() + b"\0")
            if h.hexdigest() != self.manifest["source_sha256"]:
                raise StaleGeneratedCode(
                    "the symbolic model or code generator changed since generated/ was written: "
                    "run `make derive`")
            self._check_actuators()
        if self.manifest["tools"]["casadi"] != ca.__version__:
            fix = ("install the pinned version (`make venv`) or run `make derive`"
                   if self.root is not None else
                   f"install casadi=={self.manifest['tools']['casadi']}, the version haa_sym pins")
            raise StaleGeneratedCode(
                f"generated/ was written by casadi {self.manifest['tools']['casadi']}, this is "
                f"casadi {ca.__version__}: {fix}")

    def _check_actuators(self) -> None:
        """The built-in actuator files' topologies must be the ones generated (their values may
        change freely: they are inputs of the generated functions)."""
        have = {(name, fp) for fp, t in self.manifest["topologies"].items() for name in t["actuators"]}
        want = set()
        for path in builtin_actuators(self.root / "model"):
            try:
                want.add((path.name, load_params(path).plant.topology.fingerprint))
            except ParameterError:
                continue          # a broken file is reported when it is used, with its own message
        if want - have or {n for n, _ in have} - {n for n, _ in want}:
            changed = sorted({n for n, _ in want ^ have})
            raise StaleGeneratedCode(
                f"the topology of the built-in actuator file(s) {changed} changed since generated/ "
                "was written: run `make derive`")

    @property
    def c_file(self) -> Path:
        return self.dir / f"{self.manifest['library']}.c"

    @property
    def function_names(self) -> list[str]:
        return list(self.manifest["functions"])


class Compiler:
    """Compile one C file into a shared library cached by content hash.

    Parameters
    ----------
    cc : str, optional
        Compiler command, split like a shell word list ("gcc -O0", "ccache gcc"); default env
        ``CC``, else the first of cc, gcc, clang on PATH.
    cache_dir : str or Path, optional
        Default env ``HAA_SYM_CACHE``, else ``$XDG_CACHE_HOME/haa_sym`` (``~/.cache/haa_sym``).
    """

    def __init__(self, cc: str | None = None, cache_dir: str | Path | None = None):
        cc = cc or os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") \
            or shutil.which("clang")
        try:
            self.argv = shlex.split(cc) if cc else []
        except ValueError as exc:
            raise CompilerError(f"CC = {cc!r} cannot be split into a command ({exc})") from None
        if not self.argv or not shutil.which(self.argv[0]):
            raise NoCompiler(f"no C compiler found (CC = {cc!r}; set CC or install gcc)"
                             if cc else "no C compiler found (set CC or install gcc)")
        self.cc = cc
        self.cache = Path(cache_dir or default_cache_dir())

    def _version(self) -> str:
        try:
            out = subprocess.run([*self.argv, "--version"], capture_output=True, text=True)
        except OSError:
            return self.cc
        return out.stdout.splitlines()[0] if out.stdout else self.cc

    @staticmethod
    def digest_path(library: Path) -> Path:
        """Where the SHA-256 of ``library`` is recorded (written after the library)."""
        return library.with_name(library.name + ".sha256")

    def verified(self, library: Path) -> bool:
        """True if ``library`` exists and matches its recorded SHA-256."""
        try:
            recorded = _read_regular(self.digest_path(library), 4096).decode("ascii").strip()
            return _sha256(library) == recorded
        except (OSError, UnicodeDecodeError):      # missing, not a regular file, or garbage
            return False

    @staticmethod
    def _load_error(library: Path | str, symbols) -> str | None:
        """None if ``library`` loads as a shared library exporting every name of ``symbols``,
        else why not. A compiler command that exits 0 without linking (``CC=true``,
        ``CC="gcc -c"``) leaves an empty file or an object file: recorded, it would make every
        later run fail inside CasADi."""
        # the check loads a private copy: a library mapped into this process must never be the
        # file the cache later replaces or a damaged file is rewritten over (a mapped file
        # changed in place faults with SIGBUS when its pages are next touched, e.g. at exit);
        # the copy is unlinked at once, which leaves the mapping valid
        fd, copy = tempfile.mkstemp(suffix=".so", prefix=".haa_check_")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(Path(library).read_bytes())
            try:
                lib = ctypes.CDLL(copy)
            except OSError as exc:
                return f"it is not a loadable shared library ({str(exc).splitlines()[0].replace(copy, str(library))})"
        finally:
            os.unlink(copy)
        missing = [s for s in symbols if not hasattr(lib, s)]
        return f"it does not export {missing}" if missing else None

    def build(self, c_file: Path, symbols: tuple[str, ...] = ()) -> Path:
        """The verified shared library built from ``c_file``; (re)built if absent, damaged or
        not loadable with every function of ``symbols`` (checked before its digest is
        recorded, and again when a recorded one is used)."""
        src = c_file.read_bytes()
        key = hashlib.sha256(src + "\0".join((self._version(), *self.argv) + CFLAGS).encode()
                             ).hexdigest()[:24]
        target = self.cache / key / (c_file.stem + ".so")
        if self.verified(target) and self._load_error(target, symbols) is None:
            return target
        # something else took the library's or its digest's name in our cache (a directory, a
        # FIFO): the cache is ours to repair
        for odd in (target, self.digest_path(target)):
            _clear_odd(odd)
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CompilerError(
                f"the compiled-code cache {self.cache} (HAA_SYM_CACHE, default "
                f"~/.cache/haa_sym) cannot be created: {exc.strerror or exc}; allowed: a writable "
                "directory") from None
        # Both files are written under temporary names and renamed: a concurrent process sees
        # the old or the new file, never a partial one; a library whose digest is not (yet)
        # the recorded one is rebuilt, never loaded.
        fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".so")
        os.close(fd)
        try:
            try:
                proc = _run_compiler([*self.argv, *CFLAGS, str(c_file), "-o", tmp, "-lm"], target.parent)
            except OSError as exc:
                raise CompilerError(f"cannot run the C compiler CC = {self.cc!r}: {exc}") from None
            if proc.returncode != 0:
                tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-15:])
                raise CompilerError(
                    f"compiling {c_file} with CC = {self.cc!r} failed (exit status "
                    f"{proc.returncode}); set CC to a working C compiler. Compiler output:\n"
                    f"{tail or '(none)'}")
            why = self._load_error(Path(tmp).resolve(), symbols)
            if why is not None:
                raise CompilerError(
                    f"compiling {c_file} with CC = {self.cc!r} exited 0 but {why}; allowed: a CC that "
                    "compiles and links a shared library (e.g. CC=gcc; the flags "
                    f"{' '.join(CFLAGS)} are added)")
            digest = _sha256(tmp)
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".sha256")
        with os.fdopen(fd, "w") as f:
            f.write(digest + "\n")
        os.replace(tmp, self.digest_path(target))
        return target


def _run_compiler(argv: list[str], workdir: Path) -> subprocess.CompletedProcess:
    """Run the C compiler ``argv`` so that an interrupted build leaves nothing behind.

    The compiler runs in a process group of its own and with ``TMPDIR`` set to a fresh
    directory below ``workdir``: on Ctrl-C or SIGTERM (:class:`haa_sym.errors.Terminated`) the
    whole group (the driver, ``cc1``, ``as``, ``ld``) gets SIGTERM (gcc's driver then deletes its
    temporaries), SIGKILL after :data:`COMPILER_GRACE_S`, and the directory is removed. Without
    this, killing the driver alone left ``cc1`` running and its ``/tmp/cc*.s`` files behind."""
    tmpdir = tempfile.mkdtemp(dir=workdir, prefix="cc-tmp.")
    try:
        with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True, env={**os.environ, "TMPDIR": tmpdir}) as proc:
            try:
                out, err = proc.communicate()
            except BaseException:
                _stop_group(proc)
                raise
        return subprocess.CompletedProcess(argv, proc.returncode, out, err)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)


# how long an interrupted compiler group has to exit on SIGTERM before SIGKILL, s
COMPILER_GRACE_S = 2.0


def _stop_group(proc: subprocess.Popen) -> None:
    """SIGTERM to the compiler's process group, then SIGKILL to whatever of it is left."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(COMPILER_GRACE_S)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


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
                self.library = comp.build(self.code.c_file, tuple(self.code.function_names))
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

    def run_simulation(self, sample: str, step: str, n_sub: int, x: np.ndarray, xc: np.ndarray,
                       exo: np.ndarray, ctrl: np.ndarray, plant: np.ndarray, *, scale=None,
                       tol: float | None = None, peaks: bool = False, stick_rows=None,
                       slopes=(0.0,), pieces=(1.0,), whole: int = 0, carry=None):
        """Run the simulation's sample loop (``codegen/driver.c``): per column of ``exo``
        (n_exo x n_steps) the generated ``sample`` function, then ``step`` n_sub times
        (``haa_simulate``); or, with ``scale`` and ``tol``, ``plant`` holding
        len(slopes)^len(stick_rows) tables of n_sub parameter vectors of levels 0..n_sub-1
        (2^level substeps), the table chosen per substep from the nearest entries of ``slopes``
        to 1 - tanh(stick_rows . x)^2 (one base-len(slopes) digit per row), the level per sample
        by step doubling (``haa_simulate_adaptive``).

        The drive's dead time (``whole`` samples and, with two ``pieces``, a fraction): ``plant``
        holds one parameter vector (or set of tables) per piece, the sample interval runs in
        ``len(pieces)`` pieces, piece p holding the command (``u[0]``) of the sample
        ``whole + len(pieces) - 1 - p`` before (0 before t = 0) and the jitter share ``delta``
        x ``pieces[p]`` (the driver's docstring in ``codegen/driver.c``).

        ``carry``: the loop's state besides ``x`` and ``xc`` as the last segment left it
        (:meth:`carry_size` reals: the adaptive level kept last and its difference, the delay
        line; ``codegen/driver.c``, ``haa_carry_out``), or None for a run from t = 0. With it, a
        run of n1 samples continued over n2 more (``x``, ``xc``, ``carry`` of the first passed
        to the second) takes exactly the steps of one run of n1 + n2 samples.

        Returns ``(y, x_final, xc_final, extra, carry_final)`` with ``y`` of shape (n_steps,
        n_y); ``extra`` is the level per sample (adaptive), the peak |x_i| over the sample
        instants (``peaks``), else None. Compiled: one C call for the whole run. VM: the same
        loop in Python over CasADi's VM (slow; the same numbers up to rounding).
        """
        fs, fp = self[sample], self[step]
        x = np.array(x, dtype=float).copy()
        xc = np.array(xc, dtype=float).copy()
        exo = np.asfortranarray(np.asarray(exo, dtype=float))
        ctrl = np.ascontiguousarray(ctrl, dtype=float)
        plant = np.ascontiguousarray(plant, dtype=float)
        n_exo, n = exo.shape
        n_y = fs.numel_out(2)
        adaptive = scale is not None
        levels = n_sub if adaptive else 0
        psize = fp.numel_in(3)
        rows = np.zeros((0, x.size)) if stick_rows is None else np.ascontiguousarray(stick_rows, dtype=float)
        slopes = np.ascontiguousarray(slopes, dtype=float)
        pieces = np.ascontiguousarray(pieces, dtype=float)
        n_pieces, whole = len(pieces), int(whole)
        carry_in = carry is not None
        carry = np.zeros(self.carry_size(whole, n_pieces)) if carry is None else \
            np.array(carry, dtype=float).copy()
        if carry.size != self.carry_size(whole, n_pieces):
            raise ValueError(f"carry has {carry.size} values, expected {self.carry_size(whole, n_pieces)}")
        stride = len(slopes) ** len(rows) * levels * psize if adaptive else psize
        if n_pieces < 1 or whole < 0 or plant.size != n_pieces * stride:
            raise ValueError(f"{step}: plant has {plant.size} values, expected {n_pieces} pieces x "
                             f"{len(slopes) ** len(rows) if adaptive else 1} x {max(levels, 1)} x {psize}; "
                             f"whole = {whole} (>= 0)")
        for arr, i, f, what in ((x, 0, fs, "x"), (xc, 1, fs, "xc"), (ctrl, 3, fs, "par"),
                                (plant[:psize], 3, fp, "plant par")):
            if arr.size != f.numel_in(i):
                raise ValueError(f"{f.name()}: {what} has {arr.size} values, expected {f.numel_in(i)}")
        if n_exo != fs.numel_in(2):
            raise ValueError(f"{sample}: exo has {n_exo} rows, expected {fs.numel_in(2)}")
        if self.backend != "compiled":
            return self._simulate_vm(fs, fp, n_sub, x, xc, exo, ctrl, plant, scale, tol, peaks, rows,
                                     slopes, pieces, whole, carry if carry_in else None)
        lib = self._cdll()
        y = np.empty((n, n_y))
        vp = ctypes.c_void_p
        fns = (ctypes.cast(getattr(lib, sample), vp), ctypes.cast(getattr(lib, f"{sample}_work"), vp),
               ctypes.cast(getattr(lib, step), vp), ctypes.cast(getattr(lib, f"{step}_work"), vp))
        if adaptive:
            scale = np.ascontiguousarray(scale, dtype=float)
            extra = np.empty(n)
            flag = lib.haa_simulate_adaptive(*fns, levels, psize, x.size, xc.size, fp.numel_in(1),
                                             x.ctypes.data, xc.ctypes.data, exo.ctypes.data, n_exo,
                                             ctrl.ctypes.data, plant.ctypes.data, scale.ctypes.data,
                                             float(tol), rows.ctypes.data, len(rows),
                                             slopes.ctypes.data, len(slopes), y.ctypes.data, n_y,
                                             extra.ctypes.data, n, n_pieces, stride,
                                             pieces.ctypes.data, whole, carry.ctypes.data, int(carry_in))
        else:
            extra = np.empty(x.size) if peaks else None
            flag = lib.haa_simulate(*fns, int(n_sub), x.size, xc.size, fp.numel_in(1),
                                    x.ctypes.data, xc.ctypes.data, exo.ctypes.data, n_exo,
                                    ctrl.ctypes.data, plant.ctypes.data, y.ctypes.data, n_y,
                                    None if extra is None else extra.ctypes.data, n, n_pieces, stride,
                                    pieces.ctypes.data, whole, carry.ctypes.data, int(carry_in))
        if flag:
            raise RuntimeError(f"generated {sample} / {step} failed (code {flag})")
        return y, x, xc, extra, carry

    @staticmethod
    def carry_size(whole: int, n_pieces: int) -> int:
        """Reals of :meth:`run_simulation`'s ``carry``: level, difference, the delay line's head
        and its ``whole + n_pieces`` commands."""
        return 3 + int(whole) + int(n_pieces)

    @staticmethod
    def _simulate_vm(fs, fp, n_sub, x, xc, exo, ctrl, plant, scale, tol, peaks, rows, slopes, pieces, whole,
                     carry=None):
        """:meth:`run_simulation` in Python over CasADi's VM: the C drivers' loops, line by line."""
        n = exo.shape[1]
        y = np.empty((n, fs.numel_out(2)))
        psize = fp.numel_in(3)
        n_pieces = len(pieces)
        stride = plant.size // n_pieces
        size = whole + n_pieces
        # the drive's delay line, newest first (the C ring read from its head backwards)
        ring = np.zeros(size)
        extra = np.empty(n) if scale is not None else (np.zeros(x.size) if peaks else None)
        lev, err_last = 0, tol + 1 if tol is not None else 0.0
        if carry is not None:
            head = int(carry[2])
            ring = np.array([carry[3 + (head - j) % size] for j in range(size)])
            if scale is not None:
                lev, err_last = int(carry[0]), float(carry[1])

        def table(xx, p):
            index = sum(int(np.argmin(np.abs(1 - np.tanh(rows[r] @ xx) ** 2 - slopes))) * len(slopes) ** r
                        for r in range(len(rows)))
            return plant[p * stride + index * n_sub * psize:p * stride + (index + 1) * n_sub * psize]

        def advance(x0, ups, ss, lev):
            for p in range(n_pieces):
                for _ in range(2 ** lev):
                    x0 = np.asarray(fp(x0, ups[p], ss[p], table(x0, p)[lev * psize:(lev + 1) * psize])).ravel()
            return x0
        for k in range(n):
            if peaks and scale is None:
                extra = np.maximum(extra, np.abs(x))
            u, xc_next, yk = fs(x, xc, exo[:, k], ctrl)
            y[k] = np.asarray(yk).ravel()
            xc = np.asarray(xc_next).ravel()
            u = np.asarray(u, dtype=float).ravel()
            ring = np.roll(ring, 1)
            ring[0] = u[0]
            ups = [np.concatenate([[ring[whole + n_pieces - 1 - p]], u[1:]]) for p in range(n_pieces)]
            ss = [exo[-1, k] * pieces[p] for p in range(n_pieces)]
            if scale is None:
                for p in range(n_pieces):
                    for _ in range(n_sub):
                        x = np.asarray(fp(x, ups[p], ss[p], plant[p * stride:(p + 1) * stride])).ravel()
                continue
            # driver.c's rule: the pair one level coarser than the level kept last, two when
            # the last difference was below tol / 32
            lev = min(max(lev - (2 if err_last <= tol / 32.0 else 1), 0), n_sub - 2)
            xa = advance(x, ups, ss, lev)
            while True:
                xb = advance(x, ups, ss, lev + 1)
                err = np.max(np.abs(xa - xb) / scale)
                lev += 1
                if err <= tol or lev + 1 >= n_sub:
                    err_last = err
                    break
                xa = xb
            x = xb
            extra[k] = lev
        # the C layout of the carry with head = 0: the command j samples back at index -j
        c_ring = np.empty(size)
        c_ring[(-np.arange(size)) % size] = ring
        out = np.concatenate([[lev if scale is not None else 0, err_last if scale is not None else 0.0, 0.0],
                              c_ring])
        return y, x, xc, extra, out

    def _cdll(self):
        if getattr(self, "_lib", None) is None:
            lib = ctypes.CDLL(str(self.library))
            lib.haa_columns.restype = ctypes.c_int
            lib.haa_columns.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong,
                                        ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong,
                                        ctypes.c_longlong, ctypes.c_longlong, ctypes.c_void_p,
                                        ctypes.c_void_p]
            lib.haa_simulate.restype = ctypes.c_int
            ll, vp = ctypes.c_longlong, ctypes.c_void_p
            lib.haa_simulate.argtypes = [vp] * 4 + [ll] * 4 + [vp] * 3 + [ll] + [vp] * 3 + [ll] + [vp, ll] + \
                [ll, ll, vp, ll, vp, ll]
            lib.haa_simulate_adaptive.restype = ctypes.c_int
            lib.haa_simulate_adaptive.argtypes = [vp] * 4 + [ll] * 5 + [vp] * 3 + [ll] + [vp] * 3 + \
                [ctypes.c_double, vp, ll, vp, ll, vp, ll, vp, ll, ll, ll, vp, ll, vp, ll]
            self._lib = lib
        return self._lib

    @property
    def capacities(self) -> list[int]:
        return list(self.code.manifest["capacities"])


@functools.lru_cache(maxsize=None)
def evaluators(backend: str = "auto") -> Evaluators:
    """The process-wide :class:`Evaluators` for ``backend`` (compiled once, then cached)."""
    return Evaluators(backend)
