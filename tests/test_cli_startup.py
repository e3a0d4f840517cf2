"""What starting ``haa-sym`` imports: a structural check (sys.modules of a fresh interpreter), not
a timing test. ``import haa_sym`` imports none of its submodules (its names are lazy), building
``haa-sym``'s parser imports no command's module, a command's parser only its own (docs/startup.md),
and ``import haa_sym.cli`` and ``import haa_sym`` must not import the heavy
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
from haa_sym.cli import COMMANDS

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
    package, cli, schedule = _imported("import haa_sym", "import haa_sym.cli",
                                       "haa_sym.cli.parser()[0].parse_args(['schedule'])")
    # the probe sees the imports it measures: a probe that imported nothing would pass vacuously
    assert "haa_sym" in package and "haa_sym.cli" in cli
    assert {"haa_sym.cli.schedule", "haa_sym.design.schedule", "haa_sym.loop", "casadi"} <= set(schedule)
    assert _heavy(package) == []
    assert _heavy(cli) == []
    assert _heavy(schedule) == []


# what no command but their own may import: the other families of commands and their dependencies
OTHERS = ("haa_sym.fit", "haa_sym.explore", "haa_sym.robot", "haa_sym.paper", "haa_sym.check", "haa_sym.cli.identify",
          "haa_sym.cli.explore", "haa_sym.cli.robot_import", "haa_sym.cli.robot_mujoco", "haa_sym.cli.robot_ros2",
          "haa_sym.cli.analyses", "haa_sym.cli.paper", "haa_sym.cli.tune", "haa_sym.cli.simulate",
          "haa_sym.cli.describe", "haa_sym.analysis.contact", "mujoco", "panel", "tqdm.asyncio", "asyncio")


def _among(modules: list[str], prefixes) -> list[str]:
    return sorted(m for m in modules if any(m == p or m.startswith(p + ".") for p in prefixes))


def test_import_haa_sym_imports_no_submodule():
    """``import haa_sym`` binds its public names lazily (PEP 562): no scipy, no CasADi, not even
    numpy, and no submodule of its own; the first use of a name imports what it needs."""
    package, first_use = _imported("import haa_sym", "haa_sym.ClosedLoop")
    assert _among(package, ("scipy", "numpy", "casadi", "importlib.metadata")) == []
    assert [m for m in package if m.startswith("haa_sym.")] == []
    assert {"haa_sym.loop.closed_loop", "scipy.linalg", "casadi"} <= set(first_use)


def test_parser_imports_no_command_module():
    """Building the parser and ``haa-sym --help`` import no command's module; parsing one command
    imports that command's module only (haa_sym.cli.COMMANDS), not the other commands' (the fit,
    the explorer, the robot tools, the paper, the other analyses)."""
    cli, top_help, schedule, regions = _imported(
        "import haa_sym.cli", "haa_sym.cli.parser()[0].format_help()",
        "haa_sym.cli.parser()[0].parse_args(['schedule'])",
        "haa_sym.cli.parser()[0].parse_args(['regions'])")
    commands = sorted({module for module, _help in COMMANDS.values()})
    assert _among(cli + top_help, commands + ["haa_sym.cli.common", "haa_sym.loop", "haa_sym.analysis", "scipy",
                                              "casadi", "numpy", "importlib.metadata"]) == []
    assert "haa_sym.cli.schedule" in schedule and "haa_sym.cli.analyses" in regions
    assert _among(schedule, OTHERS) == []
    # regions after schedule: what regions adds is its own (analyses, boundaries), no other family's
    assert _among(regions, [o for o in OTHERS if o not in ("haa_sym.cli.analyses", "haa_sym.analysis.contact")]) == []


def test_the_probe_sees_a_heavy_import():
    """The check above can fail: a heavy module imported on the way (scipy.stats by
    scipy.signal) is caught."""
    _, added = _imported("import haa_sym.cli", "import scipy.signal")
    assert {"scipy.signal", "scipy.stats"} <= set(_heavy(added))
