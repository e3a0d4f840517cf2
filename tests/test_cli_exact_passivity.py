"""`--option passivity=exact` end to end (issue 24): `contact`, `boundary` and `passivity` on the
bundled QDD leg (the bundled actuator with points passive under both tests), small grids."""
import json

import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.passivity import passivity
from haa_sym.analysis.regions import RegionMap
from haa_sym.cli import main
from haa_sym.loop.options import LoopOptions

# the paper's structure on QDD (its [controller.paper]): the loop these tests were measured on,
# with passive points (the file's own impedance_current loop has few at these gains)
FAST = ["--params", "qdd_leg", "--set", "structure=paper", "--option", "n_omega=200"]


def test_contact_exact(tmp_path, capsys):
    """An environment spring on the port body is lossless and in parallel with the port: it adds
    K_env / s to the continuous port impedance and leaves its Hermitian part alone, so the exact
    test's verdict cannot change with K_env where the loop stays stable. At P_gain 1, D_gain 3.6
    the exact test finds every stiffness passive, while the paper's sampled-port approximation puts
    a non-passive interval above ~6.8e4 Nm/rad (an artefact of sampling the port, on the
    conservative side); at D_gain 10 the exact test's non-passive interval runs exactly up to the
    start of the unstable one."""
    out, png = tmp_path / "c.json", tmp_path / "c.png"
    args = ["contact", *FAST, "--P-gain", "1", "--D-gain", "3.6", "--K-range", "1:1e5", "--n-scan", "8"]
    assert main([*args, "--option", "passivity=exact", "--out", str(out), "--plot", str(png)]) == 0, \
        capsys.readouterr().err
    d = json.loads(out.read_text())
    assert d["unstable_intervals"] == [] and d["not_passive_intervals"] == []
    assert "dissipation deficit" in d["not_passive"] and d["meta"]["options"]["passivity"] == "exact"
    assert png.stat().st_size > 1000
    assert main([*args, "--out", str(out)]) == 0                   # the paper's test: an interior end
    (lo, hi), = json.loads(out.read_text())["not_passive_intervals"]
    assert 1.0 < lo < hi == 1e5
    args[args.index("--D-gain") + 1] = "10"
    assert main([*args, "--option", "passivity=exact", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    (u_lo, u_hi), = d["unstable_intervals"]
    assert d["not_passive_intervals"] == [[1.0, u_lo]] and u_hi == 1e5


def test_boundary_exact(tmp_path, capsys):
    """The exact passivity curve (kind "passivity", as for the paper's test) passes where the exact
    test's deficit crosses its tolerance: on every 10th point of it the grid decision differs 1 %
    either side in D_gain, and the deficit there is ~0."""
    out = tmp_path / "b.json"
    assert main(["boundary", *FAST, "--P-gain", "log:1:100:12", "--D-gain", "lin:1:50:8",
                 "--option", "passivity=exact", "--out", str(out)]) == 0, capsys.readouterr().err
    d = json.loads(out.read_text())
    curves = [c for c in d["passivity"] if c["kind"] == "passivity"]
    assert curves and {c["kind"] for c in d["passivity"]} <= {"passivity", "passivity (omega_min)",
                                                                "passivity (Nyquist)"}
    P = np.concatenate([c["P_gain"] for c in curves])[::10]
    D = np.concatenate([c["D_gain"] for c in curves])[::10]
    loop = ClosedLoop(load_params("qdd_leg").with_values(structure="paper"), LoopOptions(passivity="exact", n_omega=200))
    on, lo, hi = (passivity(loop, P, D * f) for f in (1.0, 0.99, 1.01))
    assert np.all(np.isnan(on.phase_excess_deg)) and np.all(np.abs(on.dissipation_deficit) < 1e-4)
    assert np.all(lo.passive != hi.passive)


def test_passivity_and_regions_name_the_exact_measure(tmp_path, capsys):
    """Under the exact test the measure is `dissipation_deficit` (JSON rows, npz, results); the
    paper's `phase_excess_deg` is absent from the rows and NaN in the map; and the reverse."""
    out = tmp_path / "p.json"
    assert main(["passivity", *FAST, "--P-gain", "1,200", "--D-gain", "3.6,10", "--option", "passivity=exact",
                 "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["cells"]
    assert all("dissipation_deficit" in r and "phase_excess_deg" not in r for r in rows)
    assert rows[0]["status"] == "Yes" and rows[0]["dissipation_deficit"] <= 1e-7 < rows[1]["dissipation_deficit"]
    assert "exact dissipation deficit" in capsys.readouterr().out
    assert main(["passivity", *FAST, "--P-gain", "1", "--D-gain", "3.6", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["cells"]
    assert "phase_excess_deg" in rows[0] and "dissipation_deficit" not in rows[0]
    npz = tmp_path / "m.npz"
    for test in ("exact", "corrected_phase"):
        assert main(["regions", *FAST, "--P-gain", "log:1:100:6", "--D-gain", "lin:1:10:4", "--method", "grid",
                     "--option", f"passivity={test}", "--out", str(npz)]) == 0
        m = RegionMap.load(npz)
        ran, other = ((m.dissipation_deficit, m.phase_excess_deg) if test == "exact"
                      else (m.phase_excess_deg, m.dissipation_deficit))
        assert np.all(np.isnan(other)) and np.array_equal(np.isfinite(ran), m.stable)
        assert np.array_equal(m.passive, m.stable & (ran <= (1e-7 if test == "exact" else 1e-3)))


def test_a_map_written_before_the_deficit_field_loads(tmp_path):
    """An npz without `dissipation_deficit` (written before issue 24 gave the exact test its own
    field) loads with it NaN, the rest unchanged."""
    from haa_sym.analysis.regions import region_map
    m = region_map(ClosedLoop(load_params("qdd_leg"), LoopOptions(n_omega=200)), [1.0, 10.0], [1.0, 3.6],
                   method="grid", progress=False)
    arrays = {k: v for k, v in np.load(m.save(tmp_path / "new.npz")).items() if k != "dissipation_deficit"}
    np.savez(tmp_path / "old.npz", **arrays)
    old = RegionMap.load(tmp_path / "old.npz")
    assert np.all(np.isnan(old.dissipation_deficit)) and old.dissipation_deficit.shape == (2, 2)
    assert np.array_equal(old.passive, m.passive) and old.meta == m.meta
