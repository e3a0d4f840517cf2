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


def test_header_field_over_csv_limit(tmp_path):
    p = tmp_path / "longname.csv"
    p.write_text("time,voltage,torque," + "z" * 1_000_000 + "\n" + BODY.replace("\n", ",0\n"))
    with pytest.raises(ParameterError, match=r"the header is not CSV \(field larger than field limit") as e:
        _log(p)
    assert len(str(e.value)) < 400


@pytest.mark.parametrize("period", [1e-310, 1e-9, 1e94])
def test_time_column_not_in_seconds(tmp_path, period):
    """Subnormal steps blamed "--fit K_hd: zero sensitivity"; steps of 1e94 s overflowed."""
    p = tmp_path / "t.csv"
    p.write_text("time,voltage,torque\n" + "".join(f"{k * period!r},{np.sin(0.1 * k)},{0.5 * np.sin(0.1 * k)}\n"
                                                    for k in range(50)))
    with pytest.raises(ParameterError, match=r"^--log '.*t.csv': mean sampling period .* s; allowed: 1e-07 to 10 s "
                                             r"\(the time column in seconds\)$"):
        _log(p)


def test_report_with_a_huge_integer_or_a_bom(tmp_path):
    big = tmp_path / "big.json"
    big.write_text('{"parameters": {}, "rms_error": {}, "samples": ' + "9" * 100_000 + ', "sampling": {}, "meta": {}}')
    with pytest.raises(ParameterError, match=r"not a report \(Exceeds the limit \(4300 digits\)"):
        read_fit(big)
    bom = tmp_path / "bom.json"
    bom.write_text(json.dumps({"parameters": {"J_link": {"value": 1.0, "initial": 1.0, "ci95": [0.9, 1.1]}},
                               "rms_error": {}, "samples": 10, "sampling": {}, "meta": {}}), encoding="utf-8-sig")
    assert read_fit(bom)["samples"] == 10


def test_measured_header_name_bounded(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("P_gain,D_gain," + "q" * 100_000 + "\n1,2,stable\n")
    with pytest.raises(ParameterError, match="lacks") as e:
        read_measured(p)
    assert len(str(e.value)) < 600
