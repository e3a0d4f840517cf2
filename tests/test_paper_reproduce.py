"""`haa-sym reproduce --quick`: every output of `make paper` is written (coarse grids)."""
import csv
import json
import math
import re

import numpy as np
import pytest

from haa_sym.cli import main
from haa_sym.io.progress import set_progress
from haa_sym.paper.reproduce import foreign_entries
from haa_sym.analysis.torque import STEP_CONVENTION

pytestmark = pytest.mark.slow          # the whole quick reproduction (~25 s)


def test_reproduce_quick(tmp_path, capsys):
    out = tmp_path / "results"
    (out / "regions").mkdir(parents=True)                    # an earlier run's results, replaced whole
    (out / "regions" / "fig99z.npz").write_bytes(b"stale map")
    (out / "REPORT.md").write_text("# old report\n")
    try:
        assert main(["--quiet", "reproduce", "--quick", "--out", str(out)]) == 0
    finally:
        set_progress(None)
    assert capsys.readouterr().err == ""                  # --quiet: no progress messages
    assert [p.name for p in tmp_path.iterdir()] == ["results"]          # no temporary left
    assert foreign_entries(out) == []    # the rule that lets a later run replace it knows every output
    assert not (out / "regions" / "fig99z.npz").exists()
    tmp_path = out
    names = {p.name for p in tmp_path.iterdir()}
    assert {"REPORT.md", "claims.json", "table2.csv", "options_table2.csv", "fig07.png", "fig08.png",
            "fig09.png", "fig10.png", "fig11.png", "fig12.png", "fig12.csv", "fig07.csv",
            "fig07_step_info.csv", "contact.png", "contact.csv", "verify.txt"} <= names
    # every CSV: plain identifiers as headers, read back by numpy.genfromtxt unchanged
    csvs = sorted(tmp_path.rglob("*.csv"))
    assert len(csvs) >= 6
    for path in csvs:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
        assert all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", h) for h in rows[0]), (path.name, rows[0])
        data = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding="utf-8")
        assert list(data.dtype.names) == rows[0], path.name
        assert data.size == len(rows) - 1, path.name
    assert len(list((tmp_path / "regions").glob("fig*.npz"))) == 16
    claims = json.loads((tmp_path / "claims.json").read_text())
    assert claims["verify_exit_status"] == 0
    assert len(claims["table2"]) == 45
    # map points next to a boundary, and a lattice, checked against numpy eigvals inside reproduce
    cc = claims["region_crosscheck"]
    assert len(cc) == 16 and all(v["disagree"] == 0 for v in cc.values())
    assert all(v["decided"] > 0.99 * v["checked"] and v["checked"] > v["points"] / 9 for v in cc.values())
    report = (tmp_path / "REPORT.md").read_text()
    # Sec. 5: the torque loop alone is not passive wherever contact leaves it stable; the
    # impedance loop of Fig. 12 is stable and passive on the whole scan
    (lo, hi), = claims["contact_unstable_K_L2"]
    assert claims["contact_not_passive_K_L2"] == [[1.0, lo], [hi, 1e5]]
    assert claims["contact_impedance"]["unstable_K_L2"] == claims["contact_impedance"]["not_passive_K_L2"] == []
    assert f"{1.0:.1f}-{lo:.1f}, {hi:.1f}-{1e5:.1f} Nm/rad: passive at no scanned stiffness" in report
    contact = np.genfromtxt(tmp_path / "contact.csv", delimiter=",", names=True)
    assert (np.isnan(contact["phase_excess_deg"]) == (contact["spectral_radius"] >= 1)).all()
    for heading in ("## Table 2: passivity", "## Quantitative claims", "## Qualitative trends",
                    "![Fig. 8: varying beta](fig08.png)", "Quick mode"):
        assert heading in report
    # issue 24: the exact test against the paper's on every map and on Table 2, the paper's kept above
    ex = claims["exact_passivity"]
    assert len(ex["maps"]) == 16 and len(ex["table2"]) == 45
    for pid, m in ex["maps"].items():
        assert m["passive_paper"] - m["paper_only"] == m["passive_exact"] - m["exact_only"] >= 0
    assert [c["corrected_phase"] for c in ex["table2"]] == [c["computed"] for c in claims["table2"]]
    assert "## Exact sampled-data passivity against the paper's test" in report
    # issue 26: "the paper says / we compute" first, Table 2 next, the option table (108 rows at
    # paper scale) after both
    order = [report.index(h) for h in ("## Quantitative claims: the paper says / we compute",
                                       "## Table 2: passivity", "## Exact sampled-data passivity against the paper's test",
                                       "## Modelling options", "## Qualitative trends")]
    assert order == sorted(order)
    # the report's Table 2 count is the computed one
    n = sum(c["agrees"] for c in claims["table2"])
    assert f"The defaults reproduce **{n}/45**" in report
    # Fig. 7: step_info metrics, undefined (not settled in the window) as null, never NaN
    assert STEP_CONVENTION in report
    step = np.genfromtxt(tmp_path / "fig07_step_info.csv", delimiter=",", names=True)
    for s in claims["fig7"]:
        row = step[(step["K_L2"] == s["K_L2"]) & (step["alpha"] == s["alpha"])]
        assert row.size == 1
        for key in ("rise_time_10_90_s", "settling_time_2pct_s", "overshoot_pct"):
            assert s[key] is None or math.isfinite(s[key])
            assert (s[key] is None and np.isnan(row[key][0])) or row[key][0] == s[key]
