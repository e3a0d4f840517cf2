"""haa_sym.io.logs, review of issue 17: the messages of two refused logs a user easily makes
(a duplicated time stamp, a ';' or tab separated export) name the value plainly, in one line."""
import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.logs import read_log


def test_repeated_time_stamp_named_as_plain_numbers(tmp_path):
    p = tmp_path / "dup.csv"
    p.write_text("time,voltage,torque\n0,1,1\n0.25,2,1\n0.25,1,1\n")
    with pytest.raises(ParameterError) as exc:
        read_log(p, ("voltage",), ("torque",))
    msg = str(exc.value)
    assert "data row 3 (t = 0.25 after 0.25)" in msg and "np.float64" not in msg and "\n" not in msg, msg


@pytest.mark.parametrize("sep", [";", "\t"])
def test_non_comma_separator_named(tmp_path, sep):
    p = tmp_path / "export.csv"
    p.write_text(sep.join(["time", "voltage", "torque"]) + "\n" + sep.join(["0", "1", "1"]) + "\n")
    with pytest.raises(ParameterError, match=r"is one column; allowed: comma-separated columns") as exc:
        read_log(p, ("voltage",), ("torque",))
    assert "\n" not in str(exc.value)
