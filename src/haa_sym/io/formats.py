"""The one writer of result data: npz (arrays + ``meta`` as a JSON string), JSON and CSV, each
written all or nothing through :mod:`haa_sym.io.outputs` (alone, or as part of a command's
:class:`~haa_sym.io.outputs.Transaction`). Results are plain frozen dataclasses of arrays and a
``meta`` dict; :func:`result_arrays` reads them without knowing their type.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from haa_sym.io.outputs import Transaction, csv_text, transaction, write_text

__all__ = ["save_npz", "load_npz", "save_json", "save_csv", "result_arrays"]


def result_arrays(result) -> dict:
    """The array fields of a result dataclass (numpy arrays and None skipped), by name."""
    return {f.name: getattr(result, f.name) for f in dataclasses.fields(result)
            if isinstance(getattr(result, f.name), np.ndarray)}


def save_npz(path: str | Path, arrays: dict, meta: dict, tx: Transaction | None = None,
             field: str | None = None) -> Path:
    """``np.savez`` of ``arrays`` and ``meta`` (a JSON string, keys sorted) to ``path``."""
    with transaction(tx) as t, t.open(path, "wb", field) as fh:
        np.savez(fh, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return Path(path)


def load_npz(path: str | Path) -> tuple[dict, dict]:
    """(arrays, meta) of a file written by :func:`save_npz`."""
    with np.load(path) as f:
        data = {k: f[k] for k in f.files}
    return data, json.loads(str(data.pop("meta")))


def save_json(path: str | Path, data: dict, tx: Transaction | None = None, field: str | None = None) -> Path:
    """``data`` as indented JSON (NaN and inf as JSON's null would lose them: callers convert)."""
    return write_text(path, json.dumps(data, indent=1) + "\n", tx, field)


def save_csv(path: str | Path, rows: list[dict], tx: Transaction | None = None, field: str | None = None) -> Path:
    """``rows`` (dicts with the same keys, in order) as CSV with a header line."""
    return write_text(path, csv_text(rows), tx, field)
