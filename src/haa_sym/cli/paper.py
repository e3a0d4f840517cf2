"""``haa-sym verify`` (the paper's equations, haa_sym.check.verify) and ``haa-sym reproduce``
(every figure and table of the paper, haa_sym.paper.reproduce)."""
from __future__ import annotations

from haa_sym.check.verify import main as verify_main
from haa_sym.model.params import actuator_path
from haa_sym.paper.reproduce import reproduce

from haa_sym.cli.common import PARAMS_HELP, _common, _params, _parse_options


def _cmd_verify(args) -> int:
    return verify_main(["--params", str(actuator_path(args.params, "--params"))] if args.params else [])


def _cmd_reproduce(args) -> int:
    params = _params(args)
    options = _parse_options(args.option)
    reproduce(args.out, params, options, quick=args.quick, field="--out")
    return 0


def _verify_args(v) -> None:
    v.add_argument("--params", metavar="NAME|FILE", help=PARAMS_HELP)


def _reproduce_args(rp) -> None:
    _common(rp)
    rp.add_argument("--out", default="results")
    rp.add_argument("--quick", action="store_true", help="coarse grids (for tests)")


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"verify": (_verify_args, _cmd_verify), "reproduce": (_reproduce_args, _cmd_reproduce)}
