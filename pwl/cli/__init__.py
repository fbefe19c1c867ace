"""The ``pwl`` command. Each subcommand lives in its own module ``pwl.cli.<name>`` defining
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``; modules are imported only
when their command runs, so ``pwl info`` never loads the builder or the plant models.
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


def _available():
    """Commands whose module exists (a command is listed once it is implemented)."""
    out = {}
    for name, mod in COMMANDS.items():
        if importlib.util.find_spec(mod) is not None:
            out[name] = mod
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    cmds = _available()
    parser = argparse.ArgumentParser(prog="pwl", description="Piecewise-linear self-tuning engine models.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    chosen = argv[0] if argv and argv[0] in cmds else None
    for name, modname in cmds.items():
        if name == chosen:
            mod = importlib.import_module(modname)
            p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
            mod.add_arguments(p)
            p.set_defaults(_run=mod.run)
        else:
            sub.add_parser(name, help=f"(pwl {name} -h)")
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as e:  # our named errors derive from these
        print(f"pwl {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
