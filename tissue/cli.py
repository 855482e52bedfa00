"""``tissue`` command line: a thin layer over the Python API (every command is a Python call)."""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from meshes.errors import TissueError

# Each module defines add_parser(subparsers) that registers its command(s) with set_defaults(func=...).
COMMAND_MODULES = ["cmd_mesh", "cmd_solve", "cmd_verify", "cmd_converge", "cmd_jacobian",
                   "cmd_control", "cmd_implant", "cmd_demo"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tissue", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(f"tissue.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"tissue.{name}":
                continue
            raise
        mod.add_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("UFL", "FFCx", "ffcx", "root", "matplotlib"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    try:
        return int(args.func(args) or 0)
    except TissueError as exc:
        print(f"tissue {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
