"""Console entry `flightrecon`.

Each subcommand lives in its own module under `flightrecon/commands/` and exposes
`register(subparsers)`; they are discovered here so that adding a command never edits this file.
User errors (FlightReconError) print one line and exit with code 2; --debug shows the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from flightrecon import commands
from flightrecon.errors import FlightReconError
from flightrecon.memory import keep_freed_memory


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="flightrecon", description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks for user errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"{commands.__name__}.{info.name}").register(sub)
    _debug_after_subcommands(parser)
    return parser


def _debug_after_subcommands(parser: argparse.ArgumentParser) -> None:
    """Accept --debug after any (nested) subcommand too: `flightrecon fly demo --debug`. SUPPRESS
    keeps a subcommand from resetting a --debug given before it."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                if "--debug" not in child._option_string_actions:
                    child.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                                       help="show tracebacks for user errors")
                _debug_after_subcommands(child)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    keep_freed_memory()
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(args.func(args) or 0)
    except FlightReconError as exc:
        if args.debug:
            raise
        print(f"flightrecon: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("flightrecon: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
