"""Conventions users expect: --version, progress on stderr only, step_info metrics, the README
example, the backend in meta, BLAS threads."""
import importlib.metadata
import io
import os
import re
import sys
import tomllib

import numpy as np
import pytest

import haa_sym
from haa_sym import ClosedLoop, LoopOptions, RegionMap
from haa_sym.io import progress
from haa_sym.cli import main
from haa_sym.compiled.generated import evaluators
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.sweep import blas_limits
from haa_sym.analysis.torque import STEP_CONVENTION, step_info, step_response

from conftest import ROOT


# --- --version ------------------------------------------------------------------------------------
def test_version_flag_prints_the_distribution_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out == f"haa-sym {importlib.metadata.version('haa_sym')}\n"


def test_version_falls_back_to_pyproject_in_a_source_tree(monkeypatch):
    def not_installed(name):
        raise importlib.metadata.PackageNotFoundError(name)
    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    with open(ROOT / "pyproject.toml", "rb") as fh:
        assert haa_sym._version._version() == tomllib.load(fh)["project"]["version"]


# --- progress: stderr only, --quiet silences, --progress forces ----------------------------------
REGIONS = ["regions", "--P-gain", "log:1:20000:30", "--D-gain", "lin:1:50:20"]


@pytest.fixture
def reset_progress():
    yield
    progress.set_progress(None)


def test_progress_goes_to_stderr_and_quiet_silences_it(capsys, reset_progress):
    assert main(["--progress", *REGIONS]) == 0
    forced = capsys.readouterr()
    assert "region map" in forced.err and "600/600" in forced.err
    assert main(["--quiet", *REGIONS]) == 0
    quiet = capsys.readouterr()
    assert quiet.err == ""
    assert main([*REGIONS, "--quiet"]) == 0          # also after the command
    assert capsys.readouterr().err == ""
    # not a terminal, no flag: nothing either
    assert main(REGIONS) == 0
    plain = capsys.readouterr()
    assert plain.err == ""
    assert forced.out == quiet.out == plain.out and plain.out.startswith("600 points (curves):")


class _Terminal(io.StringIO):
    def isatty(self):
        return True

    def fileno(self):
        return 2


def test_progress_bar_appears_on_a_terminal(monkeypatch, capsys, reset_progress):
    """Default mode: a bar when stderr is a terminal and the work outlasts the delay (0 here
    instead of 2 s, to keep the test fast), also on a terminal reporting a 0 x 0 size (there
    tqdm alone draws nothing); --quiet wins over the terminal."""
    monkeypatch.setattr(progress, "DELAY_S", 0.0)
    monkeypatch.setattr(progress.os, "get_terminal_size", lambda fd: os.terminal_size((0, 0)))
    tty = _Terminal()
    monkeypatch.setattr(sys, "stderr", tty)
    with progress.progress(1, "sized") as bar:
        assert (bar.ncols, bar.nrows) == (80, 24)
    tty.seek(0)
    tty.truncate()
    assert main(REGIONS) == 0
    assert "region map" in tty.getvalue()
    out = capsys.readouterr().out
    tty.seek(0)
    tty.truncate()
    assert main(["-q", *REGIONS]) == 0
    assert tty.getvalue() == "" and capsys.readouterr().out == out


# --- step metrics: the python-control step_info convention ----------------------------------------
@pytest.mark.parametrize("K_L2, alpha", [(0.0, 0.94), (11.2, 0.94), (11.2, 0.0)])
def test_step_metrics_match_python_control_step_info(params, K_L2, alpha):
    control = pytest.importorskip("control")
    # 3 s: long enough for these steps to settle, so every step_info number is defined
    s = step_response(ClosedLoop(params.with_values(K_L2=K_L2)), duration=3.0, alpha=alpha)
    ref = control.step_info(s.T, s.t, yfinal=s.final_value)
    ours = s.info
    assert np.isfinite(ours["SettlingTime"])
    for key, value in ref.items():
        assert ours[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_step_info_with_the_last_sample_as_final_value_is_python_controls_default(params):
    control = pytest.importorskip("control")
    s = step_response(ClosedLoop(params.with_values(K_L2=0.0)), duration=0.3)
    ref = control.step_info(s.T, s.t)
    ours = step_info(s.t, s.T)
    for key, value in ref.items():
        assert ours[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_unsettled_step_reports_nan_not_a_number(params):
    """Fig. 7's 0.3 s window: the free leg with alpha = 0.94 rises but has not settled within 2 %
    of its final value; with alpha = 0 it does not even reach 90 %."""
    p = params.with_values(K_L2=0.0)
    on = step_response(ClosedLoop(p), duration=0.3, alpha=0.94)
    off = step_response(ClosedLoop(p), duration=0.3, alpha=0.0)
    # the final value is where the step goes: the long response ends within 2 % of it
    assert abs(step_response(ClosedLoop(p), duration=3.0).T[-1] / on.final_value - 1) < 0.02
    assert np.isfinite(on.rise_time) and abs(on.T[-1] / on.final_value - 1) > 0.02
    assert np.isnan(on.settling_time) and np.isnan(on.overshoot_pct)
    assert off.T.max() < 0.9 * off.final_value and np.isnan(off.rise_time)


def test_step_cli_states_the_convention_and_never_a_negative_overshoot(capsys, params):
    assert main(["step", "--set", "K_L2=0"]) == 0
    out = capsys.readouterr().out
    s = step_response(ClosedLoop(params.with_values(K_L2=0.0)), duration=0.3)
    assert f"rise time (10-90 %) {s.rise_time * 1e3:.1f} ms" in out
    assert "settling time (2 %) not settled within 0.3 s" in out
    assert STEP_CONVENTION in out and "overshoot -" not in out


# --- the README's Python example runs and is consistent -----------------------------------------
def test_readme_python_example(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert len(blocks) == 1
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), ns)
    m, res = ns["m"], ns["res"]
    np.testing.assert_array_equal(m.stable, res.stable)
    # the map is computed with the loop's options, and those are the documented defaults with
    # the file's sensor and port (HyQ: Eq. 2 with its damping term, the leg inertia J_L2)
    defaults = LoopOptions().to_dict()
    assert defaults["torque_damping"] is None and defaults["port"] is None
    assert m.meta["options"] == ns["loop"].options.to_dict() == {**defaults, "torque_damping": True,
                                                                 "port": "dtheta_L2"}
    saved = RegionMap.load(tmp_path / "map.npz")
    assert saved.meta["params"]["plant"]["J_L2"] == ns["params"].plant.J_L2
    assert (tmp_path / "map.png").stat().st_size > 1000


# --- meta records the backend that ran ------------------------------------------------------------
def test_meta_records_the_backend_that_ran(params):
    auto = region_map(ClosedLoop(params), [200.0], [10.0], radius=False)
    assert auto.meta["backend"] == evaluators("auto").backend
    assert auto.meta["backend"] in ("compiled", "vm")
    vm = region_map(ClosedLoop(params, backend="vm"), [200.0], [10.0], radius=False)
    assert vm.meta["backend"] == "vm"
    np.testing.assert_array_equal(vm.stable, auto.stable)


# --- BLAS threads ---------------------------------------------------------------------------------
def test_blas_limits_and_same_map(params):
    from threadpoolctl import threadpool_info

    def blas_threads():
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    before = blas_threads()
    with blas_limits(1):
        assert blas_threads() and set(blas_threads()) == {1}
    assert blas_threads() == before
    P, D = np.logspace(0, 4.3, 20), np.linspace(1, 50, 10)
    one = region_map(ClosedLoop(params), P, D, radius=False, blas_threads=1)
    untouched = region_map(ClosedLoop(params), P, D, radius=False, blas_threads=None)
    for k in ("stable", "phase_margin_deg", "passive", "phase_excess_deg"):
        np.testing.assert_allclose(getattr(one, k), getattr(untouched, k), rtol=1e-12, err_msg=k)


def test_torque_bandwidth_map_matches_the_pointwise_bandwidth(params):
    from haa_sym.analysis.torque import torque_bandwidth, torque_bandwidth_map
    p = params.with_values(K_L2=0.0)
    B, A = np.array([0.5, 1.0, 3.0]), np.array([0.0, 0.94])
    bw, stable = torque_bandwidth_map(ClosedLoop(p), B, A)
    assert stable.all()
    for i, b in enumerate(B):
        for j, a in enumerate(A):
            assert bw[i, j] == torque_bandwidth(ClosedLoop(p), beta=b, alpha=a)
    # more torque gain, more bandwidth (Sec. 3.3), with and without velocity compensation
    assert (np.diff(bw, axis=0) > 0).all()
