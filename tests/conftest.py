import os
import pathlib
import sys

# One BLAS thread per xdist worker: `make test` runs two workers on the 2-core machine, and
# OpenBLAS (numpy's) otherwise starts a thread per core in each of them, four BLAS threads
# spinning on two cores (measured on margins/boundaries/regions/plots with -n 2: 60-67 CPU s with
# the default, 51-53 with one thread each). OpenBLAS reads the variable only when it loads, so it
# is set here, before numpy is imported; the subprocesses the tests start inherit it. A value the
# user set is kept; a run without xdist keeps OpenBLAS's default, and so does a worker where a
# plugin loaded numpy first (too late then; only slower, not wrong).
if os.environ.get("PYTEST_XDIST_WORKER") and "numpy" not in sys.modules:
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import pytest  # noqa: E402

from haa_sym.model.params import load_params  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]


def pytest_addoption(parser):
    parser.addoption("--update-golden", action="store_true", default=False,
                     help="rewrite the golden files (tests/golden/) with what the code emits now, "
                          "instead of comparing with them; review the change with git diff")


@pytest.fixture
def update_golden(request) -> bool:
    """True with ``--update-golden``: a golden-file test rewrites its files instead of comparing."""
    return bool(request.config.getoption("--update-golden"))


@pytest.fixture(scope="session")
def params():
    return load_params(ROOT / "model" / "hyq_haa.toml")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private HAA_SYM_CACHE for one test module: what it compiles (a user's actuator) goes
    there, not into ~/.cache; the variable is restored afterwards."""
    with pytest.MonkeyPatch.context() as mp:
        path = tmp_path_factory.mktemp("cache")
        mp.setenv("HAA_SYM_CACHE", str(path))
        yield path


def decisions_against_reference(loop, pts, band: float = 1e-9, *, eig=None, certified: bool = True) -> dict:
    """The certified and the raw generated decisions at gain points ``pts`` (4, k) against the
    eigenvalues of the independent closed loop (haa_sym.check.reference), where the spectral radius is
    farther than ``band`` from 1.

    ``eig`` (k, n): the reference eigenvalues when the caller has them already (they are the costly
    part); ``certified=False`` checks the raw generated decision alone. Returns counts:
    ``disagree`` (wrong decisions, certified and raw added), ``bad`` (indices of the points with a
    wrong decision), ``count_disagree`` (points where no pole is within ``band`` of the circle and
    the raw Routh count of poles outside it differs from the eigenvalues'), ``decided`` (points
    farther than ``band`` from 1), ``stable``/``unstable`` (by the eigenvalues), ``near`` (within
    the band), ``refined`` and ``points``; ``rho``, the reference's spectral radius per point."""
    import numpy as np

    from haa_sym.check import reference as ref
    raw = loop.stability(*pts, certify=False)           # the generated decision alone
    mod = np.abs(ref.closed_loop_eigenvalues(loop, pts) if eig is None else eig)
    rho = mod.max(axis=1)
    away = np.abs(rho - 1) > band
    wrong_raw = (raw.stable != (rho < 1)) & away
    wrong = wrong_raw.copy()
    disagree, refined = int(wrong_raw.sum()), 0
    if certified:
        res = loop.stability(*pts)
        wrong_res = (res.stable != (rho < 1)) & away
        wrong |= wrong_res
        disagree += int(wrong_res.sum())
        refined = int(res.refined.sum())
    clear = np.all(np.abs(mod - 1) > band, axis=1)
    return {"disagree": disagree, "bad": np.flatnonzero(wrong),
            "count_disagree": int((raw.n_unstable[clear] != (mod[clear] > 1).sum(axis=1)).sum()),
            "decided": int(away.sum()), "stable": int((rho < 1).sum()), "unstable": int((rho > 1).sum()),
            "near": int((~away).sum()), "refined": refined, "points": int(pts.shape[1]), "rho": rho}


def snapshot(directory) -> dict:
    """Every entry under ``directory`` (hidden ones too) with its bytes and mtime."""
    out = {}
    for root, dirs, files in os.walk(directory):
        for name in dirs + files:
            p = os.path.join(root, name)
            st = os.stat(p)
            out[os.path.relpath(p, directory)] = (
                None if os.path.isdir(p) else open(p, "rb").read(), st.st_mtime_ns)
    return out


@pytest.fixture
def assert_refused(capsys, tmp_path, monkeypatch):
    """``assert_refused(argv, match, directory=tmp_path)``: ``haa-sym argv`` is refused the way every
    user-caused condition is: exit status 2 (argparse's own errors leave through SystemExit 2),
    exactly one line on stderr, starting "haa-sym: error: " and containing ``match`` (a plain
    substring, or each of a tuple of them), no traceback, and ``directory`` unchanged, byte for
    byte and mtime for mtime; nothing on stdout unless ``printed=True`` (a command that prints a
    first result before a later part fails: a figure that cannot be written, a margin beyond the
    memory budget). The command runs from the test's tmp_path, so a relative path cannot write
    elsewhere. Returns the stderr line."""
    from haa_sym.cli import main

    def check(argv, match, directory=None, *, printed=False):
        directory = tmp_path if directory is None else directory
        before = snapshot(directory)
        capsys.readouterr()                                      # what came before is not ours
        with monkeypatch.context() as mp:
            mp.chdir(tmp_path)
            try:
                rc = main(list(argv))
            except SystemExit as exc:
                rc = exc.code
        out, err = capsys.readouterr()
        assert rc == 2, (rc, err)
        assert err.startswith("haa-sym: error: ") and err.endswith("\n") and err.count("\n") == 1, err
        for piece in (match,) if isinstance(match, str) else match:
            assert piece in err, (piece, err)
        assert "Traceback" not in err, err
        assert printed or out == "", (out, err)
        assert snapshot(directory) == before, "a refused command changed the directory"
        return err
    return check
