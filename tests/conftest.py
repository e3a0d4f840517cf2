import pathlib

import pytest

from haa_sym.params import load_params

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def params():
    return load_params(ROOT / "model" / "hyq_haa.toml")
