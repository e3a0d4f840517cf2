"""The parser pieces ``haa-sym`` needs before it knows the command (the top-level parser and the
progress flags): argparse only, so that building the parser imports no command's module
(haa_sym.cli.COMMANDS, docs/startup.md)."""
from __future__ import annotations

import argparse


class _Parser(argparse.ArgumentParser):
    """argparse with the project's error form: one line, exit status 2 (argparse's own usage
    block is what ``--help`` is for)."""

    def error(self, message: str):
        self.exit(2, f"haa-sym: error: {message}; see `{self.prog} --help`\n")


def _progress_flags(p: argparse.ArgumentParser, default) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", action="store_true", default=default,
                   help="no progress bars or progress messages on stderr")
    g.add_argument("--progress", action="store_true", default=default,
                   help="progress bars on stderr from the start, also when it is not a terminal "
                        "(default: on a terminal, for work longer than 2 s)")
