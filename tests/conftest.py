import pathlib

import pytest

from haa_sym.params import load_params

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def params():
    return load_params(ROOT / "model" / "hyq_haa.toml")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private HAA_SYM_CACHE for one test module: what it compiles (a user's actuator) goes
    there, not into ~/.cache; the variable is restored afterwards."""
    with pytest.MonkeyPatch.context() as mp:
        path = tmp_path_factory.mktemp("cache")
        mp.setenv("HAA_SYM_CACHE", str(path))
        yield path
