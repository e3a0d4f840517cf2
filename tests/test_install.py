"""A wheel carries model/ and generated/, and the installed package finds them (issue 7).

The wheel is built without build isolation (the test extra pins setuptools) from a copy of the
build inputs, so the source tree gets no build/ or egg-info. ``.ci/run`` goes further: it
installs the wheel into a fresh virtual environment and runs a map and the verifier.
"""
import hashlib
import json
import os
import shutil
import subprocess
import sys
import zipfile

import pytest

from conftest import ROOT

pytest.importorskip("setuptools", minversion="68")
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    skip = shutil.ignore_patterns("__pycache__", "*.egg-info")
    for rel in ("src", "model", "generated"):
        shutil.copytree(ROOT / rel, src / rel, ignore=skip)
    for rel in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / rel, src / rel)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "--no-index", "-q", "-w", str(tmp / "dist"), str(src)],
                   check=True, capture_output=True, timeout=300)
    (whl,) = (tmp / "dist").glob("haa_sym-*.whl")
    return whl


@pytest.fixture(scope="module")
def site(wheel, tmp_path_factory):
    """The wheel unpacked, as pip would install it (a site-packages directory)."""
    site = tmp_path_factory.mktemp("site")
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    return site


def test_wheel_carries_model_and_generated(wheel):
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        read = z.read
        for toml in sorted((ROOT / "model").glob("*.toml")):
            assert read(f"haa_sym/_model/{toml.name}") == toml.read_bytes()
        manifest = json.loads(read("haa_sym/_generated/MANIFEST.json"))
        assert read("haa_sym/_generated/MANIFEST.json") == (ROOT / "generated/MANIFEST.json").read_bytes()
        for name, digest in manifest["files"].items():
            assert hashlib.sha256(read(f"haa_sym/_generated/{name}")).hexdigest() == digest, name
    assert {"haa_sym/_generated/haa_sym_gen.c", "haa_sym/_generated/haa_sym_gen.h"} <= names
    # pyproject.toml lists the packages by name: a new subpackage must be added there
    modules = {p.relative_to(ROOT / "src").as_posix() for p in (ROOT / "src/haa_sym").rglob("*.py")}
    assert modules <= names, f"not in the wheel: {sorted(modules - names)}"
    assert not [n for n in names if n.startswith("codegen/") or n.endswith(".so")]


def _run(site, cwd, *args, **env):
    # PYTHONPATH puts the unpacked wheel before the editable install of the source tree
    env = dict(os.environ, PYTHONPATH=str(site), **env)
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


def test_installed_layout_runs_from_any_directory(site, tmp_path, params):
    where = _run(site, tmp_path, "-c", "import haa_sym, haa_sym.model.resources as r; "
                 "print(haa_sym.__file__, r.source_root(), r.data_dir('model'))")
    pkg, root, model = where.stdout.split()
    assert pkg.startswith(str(site)) and root == "None" and model == str(site / "haa_sym/_model")
    # no compiler on PATH: the VM evaluates the installed .casadi files (no compile in a test)
    proc = _run(site, tmp_path, "-m", "haa_sym.cli", "stability", "--P-gain", "200",
                "--D-gain", "10", PATH="/nonexistent", CC="", HAA_SYM_CACHE=str(tmp_path / "cache"))
    assert proc.returncode == 0, proc.stderr
    from haa_sym import ClosedLoop
    ref = ClosedLoop(params, backend="vm").stability(200.0, 10.0, radius=True)
    assert proc.stdout == f"stable: {bool(ref.stable)}  spectral radius: {float(ref.spectral_radius):.12g}\n"
    assert os.listdir(tmp_path) == []  # nothing written where it ran


def test_damaged_install_says_reinstall(site, tmp_path):
    copy = shutil.copytree(site, tmp_path / "site")
    from haa_sym.model.actuator import HYQ
    plant = copy / f"haa_sym/_generated/{HYQ.function_name}.casadi"
    plant.write_bytes(plant.read_bytes()[:-1])
    (tmp_path / "work").mkdir()
    proc = _run(copy, tmp_path / "work", "-m", "haa_sym.cli", "stability", "--P-gain", "200",
                "--D-gain", "10")
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"haa-sym: error: {plant} does not match")
    assert "installed haa_sym package is damaged: reinstall it" in proc.stderr
    assert "make derive" not in proc.stderr and "Traceback" not in proc.stderr
