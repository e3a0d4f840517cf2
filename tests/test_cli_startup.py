"""What starting ``haa-sym`` imports: a structural check (sys.modules of a fresh interpreter), not
a timing test. ``import haa_sym.cli`` and ``import haa_sym`` must not import the heavy
dependencies that only a few commands use: sympy (verify, compiling an unbundled actuator),
scipy.signal, scipy.stats and scipy.optimize (the cross-check's reference, a fit's figure, root
finding), matplotlib (figures), panel and bokeh (the explorer), dask and distributed (the
schedule's sweeps), pint (files in units other than SI), python-control (to_statespace). Each
of them costs a process 0.2-0.75 s of import (docs/architecture.md), which ``haa-sym identify``'s
whole-process speed target (docs/identify.md) cannot afford."""
import json
import os
import subprocess
import sys

from conftest import ROOT

HEAVY = ("sympy", "scipy.signal", "scipy.stats", "scipy.optimize", "matplotlib", "panel", "bokeh", "dask",
         "distributed", "pint", "control")

# one fresh interpreter per probe: the modules each statement added to sys.modules, in order
PROBE = """
import json, sys
added = []
for statement in {statements!r}:
    before = set(sys.modules)
    exec(statement)
    added.append(sorted(set(sys.modules) - before))
print(json.dumps(added))
"""


def _imported(*statements: str) -> list[list[str]]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-c", PROBE.format(statements=statements)], check=True,
                         capture_output=True, text=True, env=env, cwd=ROOT)
    return json.loads(out.stdout)


def _heavy(modules: list[str]) -> list[str]:
    return sorted(m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY))


def test_start_imports_no_heavy_dependency():
    package, cli = _imported("import haa_sym", "import haa_sym.cli")
    # the probe sees the imports it measures: a probe that imported nothing would pass vacuously
    assert {"haa_sym", "haa_sym.loop", "casadi"} <= set(package)
    assert {"haa_sym.cli", "haa_sym.cli.analyses", "haa_sym.check.verify", "haa_sym.fit.model"} <= set(cli)
    assert _heavy(package) == []
    assert _heavy(cli) == []


def test_the_probe_sees_a_heavy_import():
    """The check above can fail: a heavy module imported on the way (scipy.stats by
    scipy.signal) is caught."""
    _, added = _imported("import haa_sym.cli", "import scipy.signal")
    assert {"scipy.signal", "scipy.stats"} <= set(_heavy(added))
