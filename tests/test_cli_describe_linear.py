"""haa-sym describe states the linear verdict at its gain point (review of issue 19): "no limit
cycle predicted" at a linearly unstable point means the harmonic balance bounds nothing, not that
the joint is quiet. Checked against the explicit closed loop's eigenvalues (check.reference)."""
import json

import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.check import reference
from haa_sym.cli import main


@pytest.mark.parametrize("P,D", [(20000.0, 0.0), (100.0, 10.0)])
def test_describe_states_the_linear_verdict(tmp_path, capsys, P, D):
    out = tmp_path / "df.json"
    assert main(["describe", "--P-gain", str(P), "--D-gain", str(D), "--limit", "T_res=0.1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    rho = reference.spectral_radius(ClosedLoop(load_params()), P, D)
    lin = json.loads(out.read_text())["linear"]
    assert lin["stable"] == bool(rho < 1)
    assert lin["spectral_radius"] == pytest.approx(rho, rel=1e-9)
    line, = [ln for ln in printed.splitlines() if ln.startswith("linear loop at this point:")]
    assert ("UNSTABLE" in line) == (rho > 1)
    # the warning names the quantiser exactly when the loop is unstable and no stable cycle exists
    stable_cycle = any(c["stable"] for c in json.loads(out.read_text())["predictions"][0]["limit_cycles"])
    assert ("no stable cycle predicted for T_res" in line) == (rho > 1 and not stable_cycle)
