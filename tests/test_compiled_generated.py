"""Generated code: reproducible bytes, refused when stale, compiled and VM paths agree."""
import filecmp
import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from haa_sym import ClosedLoop
from haa_sym.loop import FREQ_OUTPUTS
from haa_sym.errors import StaleGeneratedCode
from haa_sym.compiled.generated import Compiler, Evaluators, GeneratedCode

from conftest import ROOT

GEN = ROOT / "generated"


def test_regeneration_is_byte_identical(tmp_path):
    # a fresh process, like `make derive`
    subprocess.run([sys.executable, "-m", "codegen.generate", "--out", str(tmp_path)], cwd=ROOT,
                   check=True, capture_output=True)
    cmp = filecmp.dircmp(tmp_path, GEN)
    different = cmp.diff_files + cmp.left_only + cmp.right_only
    assert not different, f"generated/ differs from the symbolic model in {different}: run `make derive`"


def test_no_dates_in_generated_files():
    for p in GEN.iterdir():
        # an array subscript is no date (the simulation's parameter vectors reach index 2026)
        text = re.sub(r"\[\d+\]", "[]", p.read_text(errors="replace"))
        assert "2026" not in text and "2025" not in text, p


def _copy_tree(tmp_path):
    root = tmp_path / "tree"
    shutil.copytree(ROOT / "generated", root / "generated")
    for rel in json.loads((ROOT / "generated" / "MANIFEST.json").read_text())["sources"]:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, root / rel)
    shutil.copytree(ROOT / "model", root / "model")        # the built-in actuators' topologies
    return root


def test_tampered_file_is_refused(tmp_path):
    root = _copy_tree(tmp_path)
    c = root / "generated" / "haa_sym_gen.c"
    c.write_text(c.read_text().replace("casadi_real", "casadi_real ", 1))
    with pytest.raises(StaleGeneratedCode, match="run `make derive`"):
        GeneratedCode(root / "generated", root=root)


def test_changed_symbolic_source_is_refused(tmp_path):
    root = _copy_tree(tmp_path)
    GeneratedCode(root / "generated", root=root)  # a faithful copy is accepted
    chain = root / "src/haa_sym/symbolic/chain.py"
    chain.write_text(chain.read_text() + "\n# edited\n")
    with pytest.raises(StaleGeneratedCode, match="symbolic model .* changed.*run `make derive`"):
        GeneratedCode(root / "generated", root=root)


def test_missing_manifest_is_refused(tmp_path):
    with pytest.raises(StaleGeneratedCode, match="MANIFEST.json is missing: run `make derive`"):
        GeneratedCode(tmp_path)


_PLANT = """import sys, casadi as ca, numpy as np
f = ca.external(sys.argv[2], sys.argv[1])
args = [ca.reshape(ca.DM(np.linspace(0.5, 2.0, f.numel_in(i))), *f.size_in(i)) for i in range(f.n_in())]
print(repr([np.array(r).ravel(order="F").tolist() for r in f.call(args)]))
"""


def _plant_values(lib):
    # a fresh process: truncating a library this process has mapped would crash it (SIGBUS)
    from haa_sym.model.actuator import HYQ
    return subprocess.run([sys.executable, "-c", _PLANT, str(lib), HYQ.function_name], capture_output=True,
                          text=True, check=True).stdout


@pytest.mark.slow
def test_compile_cache_by_content_hash(tmp_path):
    comp = Compiler(cache_dir=tmp_path / "cache")
    code = GeneratedCode()
    lib = comp.build(code.c_file)
    assert lib.is_file() and (tmp_path / "cache") in lib.parents
    mtime = lib.stat().st_mtime_ns
    assert comp.build(code.c_file) == lib and lib.stat().st_mtime_ns == mtime
    assert not list(GEN.glob("*.so"))
    # issue 7: a truncated cached library crashed every later run; now it is rebuilt
    before = _plant_values(lib)
    with open(lib, "r+b") as f:
        f.truncate(lib.stat().st_size // 2)
    assert Evaluators("compiled", compiler=comp).library == lib and comp.verified(lib)
    assert _plant_values(lib) == before and "nan" not in before


def test_compiled_and_vm_agree(params):
    pts = np.array([[1.0, 200.0, 20000.0, 3000.0], [1.0, 10.0, 50.0, 5.0],
                    [1.0, 2.0, 4.0, 0.7], [0.94, 0.0, 1.2, 0.5]])
    for N_av in (4, 20):
        p = params.with_values(N_av=N_av)
        a = ClosedLoop(p, backend="compiled")
        b = ClosedLoop(p, backend="vm")
        np.testing.assert_array_equal(a.basis, b.basis)
        ra, rb = a.stability(*pts, certify=False), b.stability(*pts, certify=False)
        np.testing.assert_array_equal(ra.stable, rb.stable)
        np.testing.assert_array_equal(ra.n_unstable, rb.n_unstable)
        np.testing.assert_array_equal(ra.refined, rb.refined)
        w = np.logspace(0, 3, 7)
        fa, fb = a.frequency_response(w, *pts), b.frequency_response(w, *pts)
        for k in FREQ_OUTPUTS:
            np.testing.assert_allclose(fa[k], fb[k], rtol=1e-12)


def test_no_compiler_falls_back_to_vm_with_warning(monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.warns(RuntimeWarning, match="no C compiler found.*virtual machine"):
        ev = Evaluators("auto")
    assert ev.backend == "vm"


def test_runtime_does_not_import_sympy():
    code = ("import sys, haa_sym\n"
            "from haa_sym import load_params, ClosedLoop\n"
            "ClosedLoop(load_params()).stability(200.0, 10.0)\n"
            "assert 'sympy' not in sys.modules, 'sympy imported by the runtime'\n")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_column_driver_matches_casadi_call(params):
    """codegen/driver.c runs the generated functions over all columns in one C call; it must
    give exactly what CasADi's own per-column call of the same compiled function gives."""
    from haa_sym.compiled.generated import evaluators
    ev = evaluators("compiled")
    rng = np.random.default_rng(5)
    loop = ClosedLoop(params.with_values(N_av=10), backend="compiled")
    pts = np.stack([10 ** rng.uniform(0, 4.3, 300), rng.uniform(0, 50, 300),
                    rng.uniform(0.5, 6, 300), rng.uniform(0, 1.2, 300)])
    for name, args in ((f"haa_decide{loop.capacity}", [loop.basis, loop.const, pts]),):
        fast = ev.call_columns(name, args, 2)
        ref = ev[name](*args)
        for a, b in zip(fast, ref):
            np.testing.assert_array_equal(a.ravel(), np.array(b).ravel())
    with pytest.raises(ValueError, match="rows"):
        ev.call_columns(f"haa_decide{loop.capacity}", [loop.basis, loop.const, pts[:3]], 2)


# --- damaged generated code: one message, exit 2 (issue 7) --------------------------------------
def test_missing_listed_source_is_refused_in_a_source_tree(tmp_path):
    root = _copy_tree(tmp_path)
    (root / "codegen" / "driver.c").unlink()
    with pytest.raises(StaleGeneratedCode, match=r"driver.c, a source of generated/.* is missing: "
                                                 r"run `make derive`"):
        GeneratedCode(root / "generated", root=root)


def test_installed_package_needs_no_sources(tmp_path):
    # root=None is the installed layout: no symbolic sources, the digests alone are checked
    gen = shutil.copytree(GEN, tmp_path / "generated")
    assert GeneratedCode(gen, root=None).function_names
    from haa_sym.model.actuator import HYQ
    (gen / f"{HYQ.function_name}.casadi").write_bytes(b"")
    with pytest.raises(StaleGeneratedCode, match="unset HAA_SYM_GENERATED"):
        GeneratedCode(gen, root=None)


def _edit_manifest(gen, edit):
    man = gen / "MANIFEST.json"
    m = json.loads(man.read_text())
    edit(m)
    man.write_text(json.dumps(m))


@pytest.mark.parametrize("edit,msg", [
    (lambda m: m.pop("files"), "missing or malformed: files"),
    (lambda m: m.update(functions="haa_plant"), "missing or malformed: functions"),
    (lambda m: m["files"].pop("haa_decide16.casadi"), "files['haa_decide16.casadi']"),
    (lambda m: m.update(capacities=[16, "32"]), "missing or malformed: capacities"),
    (lambda m: m["tools"].pop("casadi"), "missing or malformed: tools.casadi"),
])
def test_invalid_manifest_is_refused(tmp_path, edit, msg):
    gen = shutil.copytree(GEN, tmp_path / "generated")
    _edit_manifest(gen, edit)
    with pytest.raises(StaleGeneratedCode, match=re.escape(msg) + ".*run `make derive`"):
        GeneratedCode(gen)


def _tamper_edit_byte(gen):
    c = gen / "haa_sym_gen.c"
    data = bytearray(c.read_bytes())
    data[len(data) // 2] ^= 1
    c.write_bytes(bytes(data))
    return "haa_sym_gen.c does not match"


def _tamper_truncate_manifest(gen):
    man = gen / "MANIFEST.json"
    man.write_bytes(man.read_bytes()[:100])
    return "MANIFEST.json is unreadable"


def _snapshot(*dirs):
    return {p: p.read_bytes() for d in dirs for p in sorted(d.rglob("*")) if p.is_file()}


_REGIONS = ["-m", "haa_sym.cli", "regions", "--P-gain", "log:1:20000:5", "--D-gain", "lin:1:50:3",
            "--out", "map.npz"]


@pytest.mark.parametrize("command,tamper", [(_REGIONS, _tamper_edit_byte),
                                            (_REGIONS, _tamper_truncate_manifest),
                                            (["-m", "haa_sym.check.verify"], _tamper_truncate_manifest)])
def test_damaged_generated_code_exits_2_with_one_message(tmp_path, command, tamper):
    # a fresh process: the evaluators are cached per process
    gen = shutil.copytree(GEN, tmp_path / "generated")
    msg = tamper(gen)
    work = tmp_path / "work"
    work.mkdir()
    before = _snapshot(gen, work)
    env = dict(os.environ, HAA_SYM_GENERATED=str(gen), HAA_SYM_CACHE=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, *command], cwd=work, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("haa-sym: error: ") and msg in proc.stderr
    assert "run `make derive`" in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stdout == ""
    assert _snapshot(gen, work) == before  # nothing written, nothing changed
