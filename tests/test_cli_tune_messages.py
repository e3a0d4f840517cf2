"""haa-sym tune, review of issue 17: when no PI of the grid meets the targets, the one-line refusal
names the command's flags that widen the grid (it named only the API fields integral_range /
lead_range) and says where beta comes from (tune has no flag for it)."""
from conftest import ROOT

HD = ROOT / "model" / "harmonic_drive.toml"


def test_no_pi_refusal_names_the_flags(assert_refused):
    assert_refused(["tune", "--params", str(HD), "--out", "x.toml", "--stable-alpha", "2:3", "--n-lead", "2",
                    "--n-integral", "3"],
                   ("no PI of the search grid meets the targets", "--integral-range / --lead-range",
                    "the file's [controller] beta"))
