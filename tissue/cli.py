"""``tissue`` command line: a thin layer over the Python API (every command is a Python call).

Exit status: 0 done; 1 an answer was computed but is not valid (inverted cells, runaway
growth: the outputs are written and marked); 2 bad input (an option, a case or mesh file, an
output path), one line naming the option, file or value; 130 interrupted.
"""
from __future__ import annotations

import argparse
import difflib
import importlib
import logging
import sys

from meshes.errors import TissueError

# Each module defines add_parser(subparsers) that registers its command(s) with set_defaults(func=...).
COMMAND_MODULES = ["cmd_mesh", "cmd_solve", "cmd_verify", "cmd_converge", "cmd_jacobian",
                   "cmd_control", "cmd_implant", "cmd_demo", "cmd_dynamics", "cmd_suite"]


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block) and exit with status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="tissue", description=__doc__,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=Parser)
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(f"tissue.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"tissue.{name}":
                continue
            raise
        mod.add_parser(sub)
    return parser


def _hint(argv, extra, options=()) -> str:
    """'; did you mean --push A1=15?' for ``--push A1 15`` (a value given as its own word), or
    the closest option of the command for a misspelt one."""
    for i, word in enumerate(argv):
        if word in extra and i >= 2 and argv[i - 2] in ("--push", "--state-push") \
                and "=" not in argv[i - 1]:
            return f"; did you mean {argv[i - 2]} {argv[i - 1]}={word}?"
    for word in extra:
        if word.startswith("--"):
            close = difflib.get_close_matches(word.split("=")[0], list(options), n=1)
            if close:
                return f"; did you mean {close[0]}?"
    return ""


def _options(parser, command) -> list:
    """The option strings of ``command``'s parser."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return list(action.choices[command]._option_string_actions)
    return []


def _os_message(exc: OSError) -> str:
    """An OSError in one line: what failed and on which path."""
    why = exc.strerror or str(exc)
    paths = [p for p in (exc.filename, exc.filename2) if p is not None]
    return f"{why}: {' -> '.join(repr(str(p)) for p in paths)}" if paths else why


def main(argv=None) -> int:
    """Run ``tissue`` with ``argv`` (default sys.argv[1:]); returns the exit status."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:
            prog = f"tissue {args.command}"
            parser.exit(2, f"{prog}: error: unrecognized arguments: {' '.join(extra)}"
                           f"{_hint(argv, extra, _options(parser, args.command))} "
                           f"(see {prog} --help)\n")
    except SystemExit as exc:  # --help (0), or a bad option: its one line is printed
        return exc.code if isinstance(exc.code, int) else 2
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("UFL", "FFCx", "ffcx", "root", "matplotlib"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    prog = f"tissue {args.command}"
    try:
        return int(args.func(args) or 0)
    except TissueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a path the checks could not foresee (it changed meanwhile)
        print(f"{prog}: error: {_os_message(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted (files are written whole or not at all)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
