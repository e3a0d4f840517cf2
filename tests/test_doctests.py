"""The runnable examples in the docstrings (the ones not marked +SKIP) of every module run and
are right."""
import doctest
import importlib
import pkgutil

import pytest

import haa_sym

MODULES = sorted(m.name for m in pkgutil.walk_packages(haa_sym.__path__, "haa_sym.")
                 if not m.name.startswith("haa_sym._"))


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
