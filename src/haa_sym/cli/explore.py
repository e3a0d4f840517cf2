"""``haa-sym explore``: the interactive gain explorer in the browser (docs/explore.md).

The page needs the optional extra ``haa_sym[explore]`` (Panel, Bokeh); without it the command
says what to install and exits with status 2.
"""
from __future__ import annotations

import socket
import sys

from haa_sym.errors import ParameterError
from haa_sym.explore import app
from haa_sym.explore.state import ViewState, resolve

from haa_sym.cli.common import PARAMS_HELP

DEFAULT_PORT = 5006         # Bokeh's and Panel's own default


def _cmd_explore(args) -> int:
    if not app.available():
        print(f"haa-sym: error: {app.EXTRA_MISSING}", file=sys.stderr)
        return 2
    if not 0 < args.port < 65536:
        raise ParameterError(f"--port {args.port}; allowed: an integer from 1 to 65535")
    state = ViewState(params=args.params or "hyq_haa")
    resolve(state)                      # a bad --params is refused before any server starts
    with socket.socket() as s:          # a port in use: one line, not the server's traceback
        try:
            s.bind(("127.0.0.1", args.port))
        except OSError as exc:
            raise ParameterError(f"--port {args.port}: {exc.strerror or exc}; allowed: a free port") from None
    print(f"haa-sym explore: serving http://127.0.0.1:{args.port}/ (127.0.0.1 only; Ctrl-C stops)", flush=True)
    try:
        # Bokeh's server stops on SIGINT by itself and returns; a KeyboardInterrupt raised
        # before its handler is installed ends the same way
        app.serve(state, port=args.port, show=not args.no_browser)
    except KeyboardInterrupt:
        pass
    print("haa-sym explore: stopped", file=sys.stderr)
    return 0


def register(sub) -> dict:
    """Add ``explore`` to ``sub`` (argparse subparsers); returns {command: run(args) -> exit status}."""
    e = sub.add_parser("explore", help="interactive gain explorer in the browser (needs haa_sym[explore])")
    e.add_argument("--params", metavar="NAME|FILE", help=PARAMS_HELP)
    e.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port on 127.0.0.1 (default {DEFAULT_PORT})")
    e.add_argument("--no-browser", action="store_true", help="do not open the page in a browser")
    return {"explore": _cmd_explore}
