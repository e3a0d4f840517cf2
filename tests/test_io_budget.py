"""haa_sym.io.budget: the memory budget and its environment variable (the commands' refusals
before allocating are in test_cli_errors.py)."""
import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, memory_budget


def test_memory_budget_env(monkeypatch):
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", "512M")
    assert memory_budget() == 512 * 2**20
    with pytest.raises(ParameterError, match=r"would need about 1 GiB of memory; allowed: at most 512 MiB"):
        check_memory(2**30, "this")
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", "lots")
    with pytest.raises(ParameterError, match=r"HAA_SYM_MEMORY_BUDGET = 'lots'; allowed: a number of bytes"):
        memory_budget()
