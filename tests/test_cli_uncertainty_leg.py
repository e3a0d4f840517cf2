"""A bad --leg given with --uncertainty is refused as the leg's mistake (review of issue 17): the
message used to start "--uncertainty 'fit.json': leg = ...", blaming a valid report."""
import json

import pytest

FIT = {"parameters": {"R": {"value": 3.32, "initial": 3.0, "ci95": [2.3, 4.3]}},
       "rms_error": {}, "samples": 100, "sampling": {}, "meta": {}}


@pytest.mark.parametrize("cmd", [["regions", "--robust", "--P-gain", "10,100", "--D-gain", "1,10", "--out", "r.npz"],
                                 ["schedule", "--P-gain", "10,100", "--D-gain", "1,10", "--out", "s.csv"]])
@pytest.mark.parametrize("leg", ["retracted:retracted", "retracted:bent"])
def test_bad_leg_with_uncertainty_names_the_leg(tmp_path, assert_refused, cmd, leg):
    (tmp_path / "fit.json").write_text(json.dumps(FIT))
    err = assert_refused([*cmd, "--leg", leg, "--uncertainty", "fit.json"], f"leg = '{leg}'; allowed: two different")
    assert "--uncertainty" not in err
