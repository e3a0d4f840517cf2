"""``haa-sym explore``: the interactive gain explorer in the browser (docs/explore.md).

The page needs the optional extra ``haa_sym[explore]`` (Panel, Bokeh); without it the command
says what to install and exits with status 2.
"""
from __future__ import annotations

import socket
import sys
from pathlib import Path

from haa_sym.errors import ParameterError
from haa_sym.explore import app
from haa_sym.explore.state import ViewState, resolve
from haa_sym.model.resources import data_dir

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
    # what the page may read: the directory the server was started in, the files and directories
    # named on this command line, and the bundled actuators (docs/explore.md, "What the page may read")
    allowed = [Path.cwd(), data_dir("model")] + [Path(a) for a in args.allow or ()]
    if args.params and Path(args.params).exists():
        allowed.append(Path(args.params))
    for a in args.allow or ():
        if not Path(a).exists():
            raise ParameterError(f"--allow {a!r}: no such file or directory; allowed: an existing file or directory")
    with socket.socket() as s:          # a port in use: one line, not the server's traceback
        try:
            s.bind(("127.0.0.1", args.port))
        except OSError as exc:
            raise ParameterError(f"--port {args.port}: {exc.strerror or exc}; allowed: a free port") from None
    print(f"haa-sym explore: serving http://127.0.0.1:{args.port}/ (127.0.0.1 only; Ctrl-C stops)", flush=True)
    try:
        # Bokeh's server stops on SIGINT by itself and returns; a KeyboardInterrupt raised
        # before its handler is installed ends the same way
        app.serve(state, port=args.port, show=not args.no_browser, allowed=allowed)
    except KeyboardInterrupt:
        pass
    print("haa-sym explore: stopped", file=sys.stderr)
    return 0


def _arguments(e) -> None:
    e.add_argument("--params", metavar="NAME|FILE", help=PARAMS_HELP)
    e.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port on 127.0.0.1 (default {DEFAULT_PORT})")
    e.add_argument("--no-browser", action="store_true", help="do not open the page in a browser")
    e.add_argument("--allow", action="append", metavar="FILE|DIR",
                   help="a file, or a directory (with everything below it), the page may read besides the current "
                        "directory and --params (repeatable; e.g. a schedule or measured-points CSV kept elsewhere)")


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"explore": (_arguments, _cmd_explore)}
