"""A measured-points CSV naming a required column twice is refused (review of issue 17): the reader
took the first silently, so a file whose second P_gain column held the experiment's gains was
compared with the model at the wrong gains."""
import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.measured import read_measured


@pytest.mark.parametrize("column", ["P_gain", "D_gain", "outcome"])
def test_a_column_named_twice_is_one_line(tmp_path, column):
    header = ["P_gain", "D_gain", "outcome", column]
    row = {"P_gain": "100", "D_gain": "10", "outcome": "stable"}
    p = tmp_path / "points.csv"
    p.write_text(",".join(header) + "\n" + ",".join([row["P_gain"], row["D_gain"], row["outcome"], row[column]])
                 + "\n")
    with pytest.raises(ParameterError, match=f"line 1: header .* names {column} 2 times") as e:
        read_measured(p)
    assert "\n" not in str(e.value)


def test_the_command_refuses_it_and_writes_nothing(tmp_path, assert_refused):
    (tmp_path / "points.csv").write_text("P_gain,D_gain,outcome,P_gain\n100,10,stable,3000\n")
    assert_refused(["regions", "--P-gain", "10,100", "--D-gain", "1,10", "--measured", "points.csv",
                    "--out", "r.npz"], ("--measured 'points.csv' line 1", "P_gain 2 times"))


def test_other_columns_may_repeat(tmp_path):
    p = tmp_path / "points.csv"
    p.write_text("P_gain,D_gain,outcome,note,note\n100,10,stable,a,b\n")
    assert read_measured(p).P_gain.tolist() == [100.0]
