"""The commands about actuator files: ``haa-sym actuators`` (the bundled ones), ``haa-sym
options`` (what --set and --option accept) and ``haa-sym compile`` (a file's plant compiled ahead
of first use)."""
from __future__ import annotations

from haa_sym.compiled.generated import evaluators
from haa_sym.compiled.plant_code import compile_topology
from haa_sym.io.gridspec import GRID_SYNTAX
from haa_sym.loop import LoopOptions
from haa_sym.loop.options import ALLOWED as OPTION_ALLOWED
from haa_sym.model.params import ALIASES, actuator_path, bundled_actuators, load_params, set_keys

from haa_sym.cli.common import _common, _params


def _cmd_actuators(args) -> int:
    """The bundled actuators: name (and alias), what they are, their configurations and file."""
    aliases = {n: a for a, n in ALIASES.items()}
    for name, path in bundled_actuators().items():
        params = load_params(path)
        alias = f" (alias {aliases[name]})" if name in aliases else ""
        print(f"{name}{alias}: {params.about.get('name', '')}\n"
              f"  {params.about.get('description', '')}\n"
              f"  configurations: {', '.join(params.configurations) or 'none'}\n"
              f"  file: {path}")
    print("(--params NAME or --params FILE anywhere; copy a file to describe another actuator, "
          "docs/model.md \"Actuator files\")")
    return 0


def _table(rows: list[tuple], header: tuple[str, ...]) -> str:
    rows = [header] + [tuple(str(c) for c in r) for r in rows]
    widths = [max(len(r[i]) for r in rows) for i in range(len(header) - 1)]
    return "\n".join("  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[-1] for r in rows)


def _cmd_options(args) -> int:
    """What --set and --option accept: keys with units, allowed values and the current value."""
    params = _params(args)
    print(f"--set KEY=VALUE, keys of {params.source} ({params.about.get('name', '')}"
          f"{', configuration ' + args.configuration if args.configuration else ''}):")
    print(_table([(k, u, "-" if v is None else f"{v:g}" if isinstance(v, float) else v, allowed)
                  for k, u, allowed, v in set_keys(params)], ("key", "unit", "value", "allowed")))
    resolved = LoopOptions().resolved(params.plant.topology)
    print("--option KEY=VALUE, fields of haa_sym.LoopOptions (docs/model.md, \"Options\"):")
    rows = []
    for name in LoopOptions.field_names():
        kind, optional = LoopOptions.field_type(name)
        default = LoopOptions.field_default(name)
        shown = (f"none (here {getattr(resolved, name)})" if default is None
                 else str(default).lower() if isinstance(default, bool) else str(default))
        rows.append((name, kind.__name__ + (" or none" if optional else ""), shown, OPTION_ALLOWED[name]))
    print(_table(rows, ("option", "type", "default", "allowed")))
    print(f"--P-gain (Nm/rad) and --D-gain (Nms/rad): {GRID_SYNTAX} (haa-sym --help: which commands "
          "take a map's axes and which take points)")
    return 0


def _cmd_compile(args) -> int:
    args.file = str(actuator_path(args.file, "ACTUATOR"))
    params = load_params(args.file)
    top = params.plant.topology
    entry = evaluators().code.manifest["topologies"].get(top.fingerprint)
    if entry is not None:
        print(f"{args.file}: topology {top.fingerprint[:12]} is built in ({entry['function']} in "
              "the generated code); nothing to compile")
        return 0
    code = compile_topology(top, quiet=args.quiet)
    where = code.library if code.library is not None else f"{code.casadi_file} (CasADi's virtual machine)"
    print(f"{args.file}: topology {top.fingerprint[:12]} ({top.describe()}) compiled: {where}")
    return 0


def _compile_args(c) -> None:
    c.add_argument("file", metavar="ACTUATOR", help="actuator file (TOML) or bundled name (haa-sym actuators)")


def _no_args(parser) -> None:
    """``actuators`` takes no arguments of its own."""


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"compile": (_compile_args, _cmd_compile), "actuators": (_no_args, _cmd_actuators),
             "options": (_common, _cmd_options)}
