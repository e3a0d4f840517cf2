"""``haa-sym``: command line of haa_sym.

  haa-sym verify [--params FILE]     check the paper's equations (same as python -m haa_sym.verify)
  haa-sym stability --P-gain 200 --D-gain 10 [--params FILE] [--set KEY=VALUE ...]
                                     decide one gain point and print its spectral radius
"""
from __future__ import annotations

import argparse
import sys

from haa_sym.params import ParameterError, load_params


def _parse_set(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ParameterError(f"--set {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"--set {item!r}: {value!r} is not a number") from None
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="haa-sym", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("verify", help="check the paper's equations")
    v.add_argument("--params")
    s = sub.add_parser("stability", help="stability of one gain point")
    s.add_argument("--params")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    s.add_argument("--P-gain", type=float, required=True)
    s.add_argument("--D-gain", type=float, required=True)
    args = ap.parse_args(argv)
    try:
        if args.cmd == "verify":
            from haa_sym.verify import main as verify_main
            return verify_main(["--params", args.params] if args.params else [])
        from haa_sym.loop import ClosedLoop
        params = load_params(args.params).with_values(**_parse_set(args.set))
        res = ClosedLoop(params).stability(args.P_gain, args.D_gain)
        print(f"stable: {bool(res.stable)}  spectral radius: {float(res.spectral_radius):.12f}")
        return 0
    except ParameterError as exc:
        print(f"haa-sym: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
