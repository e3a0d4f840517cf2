"""The runnable examples in the docstrings (the ones not marked +SKIP) run and are right."""
import doctest
import importlib

import pytest

MODULES = ["haa_sym.analysis.regions", "haa_sym.analysis.passivity", "haa_sym.analysis.contact", "haa_sym.analysis.margins",
           "haa_sym.analysis.sweep", "haa_sym.analysis.torque", "haa_sym.paper.table2", "haa_sym.model.actuator",
           "haa_sym.symbolic.model", "haa_sym.design.schedule_c"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
