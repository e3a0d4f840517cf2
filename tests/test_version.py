"""haa_sym._version: the distribution's version, ``haa-sym --version``, and the fallback to
pyproject.toml in a source tree."""
import importlib.metadata
import tomllib

import pytest

import haa_sym
from haa_sym.cli import main

from conftest import ROOT


# --- --version ------------------------------------------------------------------------------------
def test_version_flag_prints_the_distribution_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out == f"haa-sym {importlib.metadata.version('haa_sym')}\n"


def test_version_falls_back_to_pyproject_in_a_source_tree(monkeypatch):
    def not_installed(name):
        raise importlib.metadata.PackageNotFoundError(name)
    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    with open(ROOT / "pyproject.toml", "rb") as fh:
        assert haa_sym._version._version() == tomllib.load(fh)["project"]["version"]
