"""``haa-sym``: command line of haa_sym.

Examples, one per command:
  haa-sym regions --set beta=2 --P-gain log:1:20000:200 --D-gain lin:1:50:100 --out map.npz --plot map.png
  haa-sym boundary --params sea --out boundary.json --plot boundary.png
  haa-sym schedule --P-gain log:1:2000:30 --D-gain lin:1:50:20 --out schedule.csv --c-out ctrl/
  haa-sym passivity --P-gain 0,200,20000 --D-gain 0,10,50 --out cells.csv   # Table 2's columns
  haa-sym stability --P-gain 200,2000 --D-gain 10 --set N_av=10           # two points, one line each
  haa-sym margins --P-gain 200 --D-gain 10
  haa-sym contact --P-gain 200 --D-gain 10 --out contact.json
  haa-sym step --set K_L2=0 --out step.csv --plot step.png                 # Fig. 7
  haa-sym simulate --params FILE --P-gain 200 --D-gain 5 --experiment disturbance-step --duration 1 --out sim.csv
  haa-sym reproduce --out results/            every figure and table of the paper + REPORT.md
  haa-sym verify --params harmonic_drive      check the equations (any actuator: the generic rows)
  haa-sym compile my_actuator.toml            compile an actuator file's plant ahead of time
  haa-sym actuators                           the bundled actuators, their configurations and files
  haa-sym options --params sea                every --set key (units, allowed) and --option value
  haa-sym tune --params sea --out sea_tuned.toml --report tune.json --plot tune.png   the torque PI (Sec. 3.2)
  haa-sym explore --params sea                the gain explorer in the browser (haa_sym[explore])
  haa-sym export-mujoco --params sea --P-gain 200 --D-gain 1 --out sea.xml   # + sea_controller.py (haa_sym[mujoco])
  haa-sym identify --params sea --log run.csv --input voltage --output torque,theta --fit K_bar,D_bar --out fitted.toml
  haa-sym import-robot hyq.urdf --joint lf_haa_joint --configuration extended:lf_kfe_joint=-0.349 --merge hyq_haa --out hyq.toml

Gains: --P-gain (P_gain, Nm/rad) and --D-gain (D_gain, Nms/rad) take the same syntax in every
command, a grid of values: 'log:START:STOP:N' (N log-spaced, 0 < START <= STOP),
'lin:START:STOP:N' (N evenly spaced, 0 <= START <= STOP), 'V1,V2,...' or one value 'V', all
>= 0. regions, boundary and schedule take the two as the axes of a map (every P_gain with every
D_gain); passivity, stability, margins and contact take points: the i-th P_gain with the i-th
D_gain (the same number of values, as the columns of Table 2), a single value pairing with every
value of the other (contact: one point).

Every analysis command takes ``--params NAME|FILE`` (a bundled actuator, ``haa-sym actuators``,
or a TOML file; default hyq_haa), ``--configuration NAME`` (e.g. retracted), ``--set KEY=VALUE``
for any key of the parameter file,
in SI units (``--set beta=2 --set N_av=10 --set J_L2=0.129 --set
Ts=0.006``) and ``--option KEY=VALUE`` for the modelling options of ``haa_sym.LoopOptions``
(``--option port=dtheta_L1 --option delay=1``); ``haa-sym options`` lists both with units,
defaults and allowed values. Bad input exits with status 2 and a message naming the field;
nothing partial is written, and missing directories of an output path are created (and removed
again if the command fails). Results go to stdout; progress bars (on a terminal, for work longer
than 2 s) to stderr; ``--quiet`` silences them, ``--progress`` forces them. ``haa-sym
--version`` prints the version.
"""
from __future__ import annotations

import argparse
import atexit
import contextlib
import importlib
import os
import re
import signal
import sys
import threading
import warnings

from haa_sym._version import version
from haa_sym.errors import CompilerError, ParameterError, StaleGeneratedCode, Terminated
from haa_sym.io.inputs import command_scope
from haa_sym.io.progress import set_progress

from haa_sym.cli.parsing import _Parser, _progress_flags

# Every command: the module that defines its arguments and runs it, and its line in `haa-sym
# --help`, in that listing's order. A command's module is imported only when that command is
# given (docs/startup.md): building the parser of `haa-sym schedule` imports neither the fit, nor
# the explorer, nor the robot tools, nor the other analyses. Each module has
# ARGUMENTS = {command: (add_arguments(parser), run(args) -> exit status)}.
COMMANDS = {
    "verify": ("haa_sym.cli.paper", "check the paper's equations"),
    "compile": ("haa_sym.cli.actuators", "compile the plant of an actuator file into the cache (ahead of first use)"),
    "actuators": ("haa_sym.cli.actuators", "the bundled actuators: name, description, configurations and file path"),
    "options": ("haa_sym.cli.actuators", "every --set key of an actuator (unit, value, allowed) and every --option "
                "(type, default, allowed)"),
    "stability": ("haa_sym.cli.analyses", "stability of gain points, one line each"),
    "regions": ("haa_sym.cli.analyses", "stability / PM / passivity map on a gain grid (Figs. 8-11)"),
    "boundary": ("haa_sym.cli.analyses", "exact stability, phase-margin and passivity boundaries in the "
                 "(P_gain, D_gain) plane (parameter-space method)"),
    "schedule": ("haa_sym.cli.schedule", "torque-gain scheduler: the largest beta per impedance that keeps "
                 "the joint stable with PM >= 30 deg for every leg configuration (CSV, embedded C)"),
    "contact": ("haa_sym.cli.analyses", "environment stiffnesses where the loop is unstable, or stable but not "
                "passive (exact ends)"),
    "passivity": ("haa_sym.cli.analyses", "passivity of Z(z) at gain pairs (Table 2, Fig. 12)"),
    "step": ("haa_sym.cli.analyses", "unit torque step, impedance loop open (Fig. 7)"),
    "margins": ("haa_sym.cli.analyses", "phase and gain margins of the torque and impedance loops at gain points"),
    "reproduce": ("haa_sym.cli.paper", "every figure and table of the paper, and REPORT.md"),
    "identify": ("haa_sym.cli.identify", "fit parameters of an actuator file to logged experiments (CSV logs)"),
    "tune": ("haa_sym.cli.tune", "the torque PI (P_t0, I_t0) of widest torque bandwidth with PM >= 30 deg and "
             "GM >= 12 dB at every configuration (Sec. 3.2), written as a new actuator file"),
    "simulate": ("haa_sym.cli.simulate", "nonlinear simulation with the [limits] of the parameter file "
                 "(saturation, friction, quantisation, noise, jitter)"),
    "describe": ("haa_sym.cli.describe", "describing-function predictions of limit cycles (saturation, "
                 "quantisation, Coulomb friction) at one gain point"),
    "explore": ("haa_sym.cli.explore", "interactive gain explorer in the browser (needs haa_sym[explore])"),
    "import-robot": ("haa_sym.cli.robot_import", "a joint's leg inertia and gravity stiffness over configurations, "
                     "from a URDF or MJCF, into an actuator file (needs haa_sym[mujoco])"),
    "export-mujoco": ("haa_sym.cli.robot_mujoco", "an MJCF of the actuator and a Python module running the "
                      "analysed controller in a MuJoCo control callback (haa_sym[mujoco])"),
    "export-ros2": ("haa_sym.cli.robot_ros2", "the certified region as ros2_control parameters (generate_"
                    "parameter_library YAML, bounds = the largest box inside it) and as C (haa_region_contains)"),
}


class _Commands(argparse._SubParsersAction):
    """argparse's sub-commands, each one's arguments added when it is the command given: every
    command is listed (name and help line) by ``haa-sym --help``, but only the command parsed
    imports its module (:data:`COMMANDS`) and gets its arguments; ``runs`` collects its handler.
    argparse calls this action with the command's name and the arguments after it, so which
    command runs is argparse's decision, never a second reading of argv."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.runs = {}

    def __call__(self, parser, namespace, values, option_string=None):
        name = values[0]
        if name in COMMANDS and name not in self.runs:
            command = self._name_parser_map[name]
            add_arguments, self.runs[name] = importlib.import_module(COMMANDS[name][0]).ARGUMENTS[name]
            add_arguments(command)
            # also after the command (haa-sym reproduce --quiet); SUPPRESS keeps the global value
            _progress_flags(command, argparse.SUPPRESS)
        super().__call__(parser, namespace, values, option_string)


def parser() -> tuple[argparse.ArgumentParser, _Commands]:
    """``haa-sym``'s parser, with every command listed but none of their arguments added (the
    command parsed adds its own), and its sub-commands action (``.runs``: the handlers)."""
    ap = _Parser(prog="haa-sym", description=__doc__.splitlines()[0],
                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--version", action=_Version)
    _progress_flags(ap, False)
    sub = ap.add_subparsers(dest="cmd", required=True, action=_Commands)
    for name, (_module, help_line) in COMMANDS.items():
        sub.add_parser(name, help=help_line)
    return ap, sub


def main(argv: list[str] | None = None) -> int:
    ap, sub = parser()
    args = ap.parse_args(argv)
    runs = sub.runs
    set_progress(False if args.quiet else True if args.progress else None)
    # every input file a command reads is recorded, and no output may replace one of them
    with _sigterm_unwinds(), command_scope(), _condensed_warnings() as floating:
        status = _run(args, runs)
    if status == 0 and floating:
        print(f"haa-sym: warning: floating-point {', '.join(floating)} during the computation (in "
              f"{', '.join(sorted(set(floating.values())))}): inputs near the ends of double precision; "
              "check the result, or use values of physical size", file=sys.stderr)
    return status


def entry() -> None:
    """The ``haa-sym`` console script and ``python -m haa_sym.cli``: :func:`main`, then the
    process ends by :func:`end` (in-process callers, e.g. the tests, call :func:`main`)."""
    try:
        code = main()
    except SystemExit as exc:           # argparse's --help, --version and usage errors
        code = exc.code
    end(code)


def end(code) -> None:
    """End the process with ``code`` (``sys.exit``'s meaning: None is 0, an int is the status,
    anything else is printed to stderr and is status 1) once what a normal exit does for the
    command's results is done: the ``atexit`` handlers (multiprocessing's children,
    weakref finalizers such as temporary directories, logging), stdout and stderr flushed.
    What is skipped is the interpreter's teardown, freeing every object of every imported
    module one by one: 0.13 s for numpy, SciPy, CasADi and dask, 0.17-0.23 s after a local
    cluster (docs/startup.md, "The end of a command"), the same on every command. Every output
    file is closed by then (:mod:`haa_sym.io.outputs` writes and renames before the command
    returns). While a non-daemon thread still runs (Python would wait for it) or where
    ``atexit._run_exitfuncs`` is missing (not CPython), the exit is Python's own.
    """
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:
        print(code, file=sys.stderr)
        status = 1
    run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)
    waiting = [t for t in threading.enumerate() if t is not threading.main_thread() and t.is_alive() and not t.daemon]
    if run_exitfuncs is None or waiting:
        sys.exit(status)
    run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            # a reader gone (haa-sym ... | head) or a stream closed: Python's own exit would
            # report it and give status 120; the command's status says more
            pass
    os._exit(status & 0xFF)          # what sys.exit(status) gives on POSIX


class _Version(argparse._VersionAction):
    """argparse's ``--version`` (the same help line and output), the version read only when the
    flag is given: reading it imports ``importlib.metadata`` (haa_sym._version)."""

    def __call__(self, parser, namespace, values, option_string=None):
        self.version = f"%(prog)s {version()}"
        super().__call__(parser, namespace, values, option_string)


# numpy's floating-point RuntimeWarnings ("overflow encountered in multiply")
_FLOATING = re.compile(r"^(overflow|underflow|invalid value|divide by zero) encountered")


@contextlib.contextmanager
def _condensed_warnings():
    """Warnings as one line each, never Python's two lines with a source line from deep inside
    the library; numpy's floating-point warnings are collected instead ({kind: where}) and
    summarised by main() in one line when the command succeeds (when it fails, its error says
    why; an overflow that was caught and refused is not news)."""
    floating: dict[str, str] = {}

    def show(message, category, filename, lineno, file=None, line=None):
        text = str(message)
        m = _FLOATING.match(text)
        if issubclass(category, RuntimeWarning) and m:
            floating.setdefault(m.group(1), f"{os.path.basename(filename)}:{lineno}")
        else:
            print(f"haa-sym: warning: {text.removeprefix('haa_sym: ')}", file=sys.stderr)
    with warnings.catch_warnings():
        warnings.showwarning = show
        yield floating


@contextlib.contextmanager
def _sigterm_unwinds():
    """SIGTERM raises :class:`Terminated` in the main thread while a command runs, so that it
    unwinds like SIGINT: without this, the default action kills the process mid-write and the
    outputs' temporaries (``.DIR.XXXX.tmp/``, ``.fig.png.XXXX.tmp``) stay behind. The previous
    handler is restored (main() is also called in-process, e.g. by the tests)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    owner = os.getpid()

    def terminate(signum, frame):
        if os.getpid() != owner:
            # a process forked from this one (a local:N worker, haa_sym.io.pool.START_METHOD)
            # inherited the handler: it ends as SIGTERM's default action would end it
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated()
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run(args, runs) -> int:
    """Run the parsed command; the errors a user can fix become one line and exit status 2."""
    try:
        return runs[args.cmd](args)
    except ParameterError as exc:
        print(f"haa-sym: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader of stdout went away (haa-sym ... | head): not an error of the command; the
        # recipe of the Python docs (signal module, "Note on SIGPIPE")
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except OSError as exc:
        print(f"haa-sym: error: {exc.strerror or exc}: {exc.filename or ''}", file=sys.stderr)
        return 2
    except RuntimeError as exc:
        # generated/ stale or damaged, or the C compiler failing: a fault the user fixes, not a bug
        if not isinstance(exc, (StaleGeneratedCode, CompilerError)):
            raise
        print(f"haa-sym: error: {exc}", file=sys.stderr)
        return 2
    except Terminated:
        # as SIGINT below: every staged output was rolled back; 128 + SIGTERM
        print("haa-sym: terminated (SIGTERM); no output written", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        # outputs are staged (haa_sym.io.outputs): an interrupted command leaves existing files as
        # they were; 128 + SIGINT, the shell's convention
        print("haa-sym: interrupted; no output written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
