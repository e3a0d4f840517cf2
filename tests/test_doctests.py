"""The runnable examples in the docstrings (the ones not marked +SKIP) run and are right."""
import doctest
import importlib

import pytest

MODULES = ["haa_sym.regions", "haa_sym.passivity", "haa_sym.contact", "haa_sym.margins",
           "haa_sym.sweep", "haa_sym.torque", "haa_sym.paper.table2", "haa_sym.actuator",
           "haa_sym.symbolic.model", "haa_sym.schedule_table", "haa_sym.schedule_c"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
