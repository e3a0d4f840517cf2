"""The runnable examples: the docstrings' (the ones not marked +SKIP) of every module and the
Python example of docs/python.md run and are right."""
import doctest
import importlib
import pkgutil
import re

import numpy as np
import pytest

import haa_sym
from haa_sym import LoopOptions, RegionMap

from conftest import ROOT

MODULES = sorted(m.name for m in pkgutil.walk_packages(haa_sym.__path__, "haa_sym.")
                 if not m.name.startswith("haa_sym._"))


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0


# --- the Python example of docs/python.md (the README's before issue 26) runs and is consistent ---
def test_docs_python_example(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "python.md").read_text(), re.S)
    assert len(blocks) == 1
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(blocks[0], "docs/python.md", "exec"), ns)
    m, res = ns["m"], ns["res"]
    np.testing.assert_array_equal(m.stable, res.stable)
    # the map is computed with the loop's options, and those are the documented defaults with
    # the file's sensor and port (HyQ: Eq. 2 with its damping term, the leg inertia J_L2)
    defaults = LoopOptions().to_dict()
    assert defaults["torque_damping"] is None and defaults["port"] is None
    assert m.meta["options"] == ns["loop"].options.to_dict() == {**defaults, "torque_damping": True,
                                                                 "port": "dtheta_L2"}
    saved = RegionMap.load(tmp_path / "map.npz")
    assert saved.meta["params"]["plant"]["J_L2"] == ns["params"].plant.J_L2
    assert (tmp_path / "map.png").stat().st_size > 1000
