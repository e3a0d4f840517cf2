"""The reader of an identification's report (fit.json, issue 17): the schema of haa-sym
identify checked field by field, one line per mistake; the box and the centres it gives."""
import json

import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.uncertainty import fit_box, fit_values, read_fit

GOOD = {"parameters": {"K_hd": {"value": 8077.0, "initial": 7000.0, "ci95": [7300.0, 8850.0]},
                       "D_hd": {"value": 16.56, "initial": 10, "ci95": [14.0, 19.0]}},
        "rms_error": {"torque": 0.01}, "samples": 30000, "sampling": {"mean_period_s": 1e-3}, "meta": {}}
KEYS = ("K_hd", "D_hd", "R")


def _write(tmp_path, data, name="fit.json"):
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def test_reads_the_box_and_the_centres(tmp_path):
    fit = read_fit(_write(tmp_path, GOOD), keys=KEYS)
    assert fit_box(fit) == {"D_hd": (14.0, 19.0), "K_hd": (7300.0, 8850.0)}
    assert fit_values(fit) == {"D_hd": 16.56, "K_hd": 8077.0}
    assert fit["source"].endswith("fit.json") and fit["samples"] == 30000


def _with(path_value):
    """GOOD with one entry replaced: ``path_value`` = (("parameters", "K_hd", "ci95"), value)."""
    data = json.loads(json.dumps(GOOD))
    keys, value = path_value
    d = data
    for k in keys[:-1]:
        d = d[k]
    if value is KeyError:
        del d[keys[-1]]
    else:
        d[keys[-1]] = value
    return data


@pytest.mark.parametrize("change, msg", [
    ((("rms_error",), KeyError), "field 'rms_error' is missing"),
    ((("samples",), 1.5), "field 'samples' = 1.5; allowed: a JSON integer"),
    ((("samples",), 0), "field 'samples' = 0; allowed: an integer >= 1"),
    ((("parameters",), {}), "'parameters' is empty"),
    ((("parameters", "K_xx"), {"value": 1, "initial": 1, "ci95": [0, 2]}), "parameters.K_xx: 'K_xx' is not a key"),
    ((("parameters", "K_hd", "ci95"), KeyError), "parameters.K_hd: field 'ci95' is missing"),
    ((("parameters", "K_hd", "ci95"), [1, 2, 3]), "parameters.K_hd.ci95 = [1, 2, 3]; allowed: [lo, hi]"),
    ((("parameters", "K_hd", "ci95"), [9000, 9500]), "parameters.K_hd.ci95 = [9000, 9500] with value 8077"),
    ((("parameters", "K_hd", "value"), "8077"), "parameters.K_hd.value = \"8077\"; allowed: a finite number"),
    ((("parameters", "K_hd", "initial"), None), "parameters.K_hd.initial = null"),
    ((("parameters", "K_hd"), [1, 2]), "parameters.K_hd = [1, 2]; allowed: an object"),
    ((("parameters", "K\nhd"), {"value": 1, "initial": 1, "ci95": [0, 2]}), "parameters.K\\nhd"),
])
def test_bad_reports_are_one_line(tmp_path, change, msg):
    with pytest.raises(ParameterError) as e:
        read_fit(_write(tmp_path, _with(change)), keys=KEYS)
    assert msg in str(e.value) and "\n" not in str(e.value) and "--uncertainty" in str(e.value)


@pytest.mark.parametrize("text, name, msg", [("[1, 2]", "fit.json", "a JSON list"),
                                             ("{", "fit.json", "not JSON (line 1"),
                                             ("{}", "fit.txt", "not a .json file"),
                                             (b"\xff\xfe", "fit.json", "not a text file (byte 0xff at offset 0")])
def test_not_a_report(tmp_path, text, name, msg):
    path = tmp_path / name
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    with pytest.raises(ParameterError) as e:
        read_fit(path)
    assert msg in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ParameterError, match="no such file"):
        read_fit(tmp_path / "none.json")
