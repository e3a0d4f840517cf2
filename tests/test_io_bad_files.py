"""The readers of logs, measured points and identification reports on hostile files (issue 26,
item 11): one line naming the row and column, bounded messages, linear-time checks, no
traceback. Each case failed before: a traceback (csv.Error, RecursionError), a 1 MB message, a
message with no row or column, or minutes of quadratic checking."""
import json
import time

import numpy as np
import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.logs import read_log
from haa_sym.io.measured import read_measured
from haa_sym.io.uncertainty import read_fit

BODY = "".join(f"{k * 1e-3},{np.sin(0.1 * k)},{0.5 * np.sin(0.1 * k)}\n" for k in range(50))


def _log(path, **kw):
    return read_log(path, ("voltage",), ("torque",), **kw)


def test_bom_log_read(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_text("time,voltage,torque\n" + BODY, encoding="utf-8-sig")
    assert _log(p).samples == 50


def test_text_field_named_by_row_and_column(tmp_path):
    p = tmp_path / "text.csv"
    p.write_text("time,voltage,torque\n" + BODY + "0.05,abc,1\n")
    with pytest.raises(ParameterError, match=r"data row 51, column 'voltage': 'abc' is not a number"):
        _log(p)


@pytest.mark.parametrize("reader, header", [(_log, "time,voltage,torque"), (read_measured, "P_gain,D_gain,outcome")])
def test_field_over_csv_limit(tmp_path, reader, header):
    p = tmp_path / "big.csv"
    p.write_text(f'{header}\n1,"{"1" * 200_000}",1\n')
    with pytest.raises(ParameterError, match=r"line 2.*not CSV \(field larger than field limit") as e:
        reader(p)
    assert len(str(e.value)) < 400


def test_wide_header_bounded_and_linear(tmp_path):
    wide = tmp_path / "wide.csv"
    wide.write_text(",".join(["time", "voltage", "torque"] + [f"c{i}" for i in range(100_000)]) + "\n")
    with pytest.raises(ParameterError, match=r"unknown column\(s\) \['c0', .*'c9', \.\.\. \(99990 more\)\]") as e:
        _log(wide)
    assert len(str(e.value)) < 400
    dup = tmp_path / "dup.csv"
    dup.write_text(",".join(["time", "voltage"] + ["torque"] * 100_000) + "\n")
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"column\(s\) \['torque'\] given twice"):
        _log(dup)
    assert time.perf_counter() - t0 < 5            # header.count per column: minutes


def test_report_nested_and_many_keys(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text('{"parameters":' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(ParameterError, match="nested too deeply"):
        read_fit(deep)
    many = tmp_path / "many.json"
    many.write_text(json.dumps({"parameters": {"J_link": {"value": 1.0, "initial": 1.0, "ci95": [0.9, 1.1]}},
                                "rms_error": {}, "samples": 10, "sampling": {},
                                "meta": {f"k{i}": i for i in range(100_000)}}))
    t0 = time.perf_counter()
    assert read_fit(many)["parameters"]["J_link"]["value"] == 1.0
    assert time.perf_counter() - t0 < 5            # names.count per name: minutes
