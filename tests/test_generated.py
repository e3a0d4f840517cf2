"""Generated code: reproducible bytes, refused when stale, compiled and VM paths agree."""
import filecmp
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from haa_sym import ClosedLoop
from haa_sym.compiled import Compiler, Evaluators, GeneratedCode, StaleGeneratedCode

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
        text = p.read_text(errors="replace")
        assert "2026" not in text and "2025" not in text, p


def _copy_tree(tmp_path):
    root = tmp_path / "tree"
    for rel in ("generated", "src/haa_sym/symbolic", "codegen"):
        shutil.copytree(ROOT / rel, root / rel)
    shutil.copy(ROOT / "src/haa_sym/params.py", root / "src/haa_sym/params.py")
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
    eom = root / "src/haa_sym/symbolic/eom.py"
    eom.write_text(eom.read_text() + "\n# edited\n")
    with pytest.raises(StaleGeneratedCode, match="symbolic model .* changed.*run `make derive`"):
        GeneratedCode(root / "generated", root=root)


def test_missing_manifest_is_refused(tmp_path):
    with pytest.raises(StaleGeneratedCode, match="MANIFEST.json is missing: run `make derive`"):
        GeneratedCode(tmp_path)


def test_compile_cache_by_content_hash(tmp_path):
    comp = Compiler(cache_dir=tmp_path / "cache")
    code = GeneratedCode()
    lib = comp.build(code.c_file)
    assert lib.is_file() and (tmp_path / "cache") in lib.parents
    mtime = lib.stat().st_mtime_ns
    assert comp.build(code.c_file) == lib and lib.stat().st_mtime_ns == mtime
    assert not list(GEN.glob("*.so"))


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
        for k in fa:
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
    from haa_sym.compiled import evaluators
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
