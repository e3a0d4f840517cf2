"""``make derive``: regenerate ``generated/`` from the symbolic model.

Writes, byte-reproducibly (no dates, sorted JSON):
  generated/haa_sym_gen.c      every CasADi Function as C, then codegen/driver.c (one translation unit)
  generated/<name>.casadi      the same Functions serialised, for CasADi's VM when no compiler
  generated/MANIFEST.json      SHA-256 of every generated file and of the sources, tool versions,
                               and the built-in actuators' topologies (fingerprint -> function, files)
The plant function of every built-in actuator (model/*.toml except paper.toml) is generated,
one per distinct topology, named haa_plant_<first 12 hex of the topology's fingerprint>.
Usage: python -m codegen.generate [--out DIR]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

import casadi as ca
import sympy

from codegen.kernels import decision_function, loop_coefficient_function
from codegen.sim_kernels import simulation_functions
from haa_sym.model.params import builtin_actuators, load_params
from haa_sym.symbolic.chain import symbolic_model
from haa_sym.symbolic.symbolic_to_casadi import plant_function

ROOT = Path(__file__).resolve().parents[1]
C_NAME = "haa_sym_gen"
DRIVER = ROOT / "codegen" / "driver.c"
# Polynomial capacities of the stability evaluators: degree N_av + 8 + delay must fit.
CAPACITIES = (16, 32, 64)
# Files whose content defines the generated code; their hash is recorded in the manifest and
# checked by the runtime (a changed source means stale generated code). The actuator files
# define it through their topology only (not their values): the manifest's "topologies" lists
# each built-in file under its topology's fingerprint, and the runtime checks that list against
# model/ (haa_sym.compiled.generated.GeneratedCode), so editing a value never stales generated/.
SOURCES = (
    "src/haa_sym/model/actuator.py",
    "src/haa_sym/compiled/layout.py",
    "src/haa_sym/symbolic/chain.py",
    "src/haa_sym/symbolic/model.py",
    "src/haa_sym/symbolic/symbolic_to_casadi.py",
    "codegen/kernels.py",
    "codegen/sim_kernels.py",
    "codegen/generate.py",
    "codegen/driver.c",
)


def builtin_topologies() -> dict[str, dict]:
    """{fingerprint: {"function", "actuators", "topology"}} of the built-in actuator files."""
    out: dict[str, dict] = {}
    for path in builtin_actuators():
        top = load_params(path).plant.topology
        entry = out.setdefault(top.fingerprint, {"function": top.function_name, "actuators": [],
                                                 "topology": top})
        entry["actuators"].append(path.name)
    return out


def functions(topologies: dict[str, dict] | None = None) -> list[ca.Function]:
    topologies = builtin_topologies() if topologies is None else topologies
    fns = [plant_function(symbolic_model(t["topology"]), t["function"]) for _, t in sorted(topologies.items())]
    fns += [loop_coefficient_function()]
    fns += [decision_function(cap) for cap in CAPACITIES]
    fns += simulation_functions()
    return fns


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def source_digest(root: Path = ROOT) -> str:
    h = hashlib.sha256()
    for rel in SOURCES:
        h.update(rel.encode() + b"\0" + (root / rel).read_bytes() + b"\0")
    return h.hexdigest()


def _write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".")
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def generate(out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    topologies = builtin_topologies()
    fns = functions(topologies)
    files: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator(f"{C_NAME}.c", {"with_header": True})
        for f in fns:
            cg.add(f)
        cg.generate(tmp + os.sep)
        for name in (f"{C_NAME}.c", f"{C_NAME}.h"):
            files[name] = Path(tmp, name).read_bytes()
    # one translation unit: the column driver uses the generated typedefs and export macro
    files[f"{C_NAME}.c"] += b"\n" + DRIVER.read_bytes()
    for f in fns:
        files[f"{f.name()}.casadi"] = f.serialize().encode()
    manifest = {
        "generator": "python -m codegen.generate (make derive)",
        "tools": {"casadi": ca.__version__, "sympy": sympy.__version__},
        "source_sha256": source_digest(),
        "sources": list(SOURCES),
        "capacities": list(CAPACITIES),
        "functions": [f.name() for f in fns],
        "library": C_NAME,
        "files": {name: sha256_bytes(data) for name, data in sorted(files.items())},
        "topologies": {fp: {"function": t["function"], "actuators": sorted(t["actuators"])}
                       for fp, t in sorted(topologies.items())},
    }
    files["MANIFEST.json"] = (json.dumps(manifest, indent=2, sort_keys=True) + "\n").encode()
    for name, data in files.items():
        _write(out / name, data)
    # nothing stale may stay behind
    for old in out.iterdir():
        if old.name not in files:
            old.unlink()
    return manifest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "generated")
    args = ap.parse_args(argv)
    m = generate(args.out)
    print(f"generated {len(m['files'])} files into {args.out} (casadi {m['tools']['casadi']}, "
          f"sympy {m['tools']['sympy']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
