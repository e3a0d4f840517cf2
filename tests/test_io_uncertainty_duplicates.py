"""A report naming a key twice is refused (review of issue 17): json.loads kept the last entry
silently, so of two intervals for R the map analysed whichever came last."""
import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.uncertainty import read_fit

TAIL = '"rms_error": {}, "samples": 3, "sampling": {}, "meta": {}'
R = '"R": {"value": 3.32, "initial": 3.0, "ci95": [%s]}'


@pytest.mark.parametrize("parameters,name", [
    ("{%s, %s}" % (R % "2.3, 4.3", R % "3.0, 3.5"), "R"),                     # a parameter twice
    ('{%s}, "samples": 4' % (R % "2.3, 4.3"), "samples"),                     # a top-level field twice
    ('{"R": {"value": 3.32, "value": 3.0, "initial": 3.0, "ci95": [2.3, 4.3]}}', "value"),
])
def test_a_name_twice_is_one_line(tmp_path, parameters, name):
    p = tmp_path / "fit.json"
    p.write_text('{"parameters": %s, %s}' % (parameters, TAIL))
    with pytest.raises(ParameterError, match=f"the name '{name}' appears twice") as e:
        read_fit(p)
    assert "\n" not in str(e.value)


def test_the_command_refuses_it_and_writes_nothing(tmp_path, assert_refused):
    (tmp_path / "fit.json").write_text('{"parameters": {%s, %s}, %s}' % (R % "2.3, 4.3", R % "3.0, 3.5", TAIL))
    assert_refused(["regions", "--robust", "--uncertainty", "fit.json", "--P-gain", "10,100", "--D-gain", "1,10",
                    "--out", "r.npz"], ("--uncertainty 'fit.json'", "'R' appears twice"))


def test_one_name_each_reads_as_before(tmp_path):
    p = tmp_path / "fit.json"
    p.write_text('{"parameters": {%s}, %s}' % (R % "2.3, 4.3", TAIL))
    assert read_fit(p)["parameters"]["R"]["ci95"] == [2.3, 4.3]
