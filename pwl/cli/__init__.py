"""The ``pwl`` command. Each subcommand lives in its own module ``pwl.cli.<name>`` defining
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``; a module imports its heavy
dependencies (the builder, the plant models, matplotlib) inside ``run``, so ``pwl info`` never
loads them.
"""
from __future__ import annotations

import argparse
import importlib
import sys

#: command -> module; the only place a command is registered.
COMMANDS = {
    "info": "pwl.cli.info",
    "bench": "pwl.cli.bench",
    "simulate": "pwl.cli.simulate",
    "build": "pwl.cli.build",
    "validate": "pwl.cli.validate",
    "run": "pwl.cli.run",
    "demo": "pwl.cli.demo",
    "trend": "pwl.cli.trend",
    "fleet": "pwl.cli.fleet",
    "tables": "pwl.cli.tables",
    "zones": "pwl.cli.zones",
    "bias": "pwl.cli.bias",
    "biastable": "pwl.cli.biastable",
}


def _parser(cmds):
    """The argument parser: one line of help per command (each module's HELP; the modules import
    their heavy dependencies only inside ``run``)."""
    from .. import __version__
    from ..errors import EXIT_CODES

    codes = "; ".join(f"{k} {v}" for k, v in EXIT_CODES.items())
    parser = argparse.ArgumentParser(
        prog="pwl", description="Piecewise-linear self-tuning engine models.",
        epilog=f"Exit codes: {codes}. 'pwl COMMAND -h' describes a command.")
    parser.add_argument("--version", action="version", version=f"pwl {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show the Python traceback of any error (default: a one-line message)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, modname in cmds.items():
        mod = importlib.import_module(modname)
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None) -> int:
    """The ``pwl`` entry point: the command's exit code; named errors (:class:`pwl.errors.PwlError`)
    and file-system errors become one line on stderr and exit 2, anything else (a bug) one line and
    exit 3; ``--debug`` re-raises instead."""
    from ..errors import EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, PwlError

    argv = sys.argv[1:] if argv is None else list(argv)
    args = _parser(COMMANDS).parse_args(argv)
    import signal
    import warnings
    shown = warnings.showwarning
    warnings.showwarning = _plain_pwl_warnings(shown)
    try:           # a TERM (a scheduler's, a container's stop) ends a command as Ctrl-C does
        term = signal.signal(signal.SIGTERM, _interrupt)
    except ValueError:    # not the main thread: leave it
        term = None
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:      # the reader of stdout went away (pwl ... | head): not an error
        _quiet_stdout()
        return 0
    except (PwlError, OSError) as e:
        if args.debug:
            raise
        print(f"pwl {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_INPUT
    except Exception as e:  # a bug: say so in one line, the traceback on request
        if args.debug:
            raise
        print(f"pwl {args.command}: internal error: {type(e).__name__}: {_one_line(e)} "
              f"(rerun with 'pwl --debug {args.command} ...' for the traceback; please report it)",
              file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        warnings.showwarning = shown
        if term is not None:
            signal.signal(signal.SIGTERM, term)


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's flush at exit does not fail again on
    the closed pipe (Python's documented way, 'Note on SIGPIPE')."""
    import os
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):      # stdout is not a file (captured): nothing to quiet
        pass


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _plain_pwl_warnings(shown):
    """A ``warnings.showwarning`` that prints a :class:`pwl.errors.PwlWarning` (a fallback taken
    on the user's input) as one line ``pwl: warning: <message>`` instead of Python's file:line and
    source line, and hands every other warning to ``shown``."""
    from ..errors import PwlWarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, PwlWarning):
            print(f"pwl: warning: {_one_line(message)}", file=file or sys.stderr)
        else:
            shown(message, category, filename, lineno, file, line)
    return show


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


if __name__ == "__main__":
    sys.exit(main())
