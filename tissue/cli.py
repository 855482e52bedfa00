"""``tissue`` command line: a thin layer over the Python API (every command is a Python call).

Global options go before or after the command: -v/--verbose (debug logging, with the C
compiler's lines while forms are first compiled), -q/--quiet (no progress lines; warnings and
errors are still printed); --version prints the version.

Exit status: 0 done; 1 an answer was computed but is not valid or not good enough (inverted
cells, runaway growth, a tolerance or accuracy not met, a load or a control loop past the range
where answers converge: the outputs are written and say so); 2 an
error named in one line: bad input (an option, a case or mesh file, an output path) or a failure
during the work (a solve that does not converge, its last converged state written; a fast solver
that diverges; an unreachable goal); 130 interrupted. Details: docs/outputs.md.
"""
from __future__ import annotations

import argparse
import contextlib
import difflib
import importlib
import logging
import sys
import warnings
from importlib import metadata
from pathlib import Path

from tissue_reference.errors import TissueError, TissueWarning

# Each module defines add_parser(subparsers) that registers its command(s) with set_defaults(func=...).
COMMAND_MODULES = ["cmd_mesh", "cmd_solve", "cmd_verify", "cmd_converge", "cmd_jacobian",
                   "cmd_control", "cmd_table1", "cmd_implant", "cmd_demo", "cmd_dynamics", "cmd_suite"]
DISTRIBUTION = "tissue-reference"  # [project] name in pyproject.toml


def version() -> str:
    """The installed distribution's version; in a source tree that is not installed, the one in
    its pyproject.toml."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        pass
    try:
        import tomllib

        with open(Path(__file__).resolve().parents[1] / "pyproject.toml", "rb") as f:
            return str(tomllib.load(f)["project"]["version"])
    except (OSError, KeyError, ValueError):
        return "unknown"


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block) and exit with status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


VERBOSE_HELP = "debug logging, with the C compiler's lines while forms are first compiled"
QUIET_HELP = "no progress lines (warnings and errors are still printed)"


def _add_global_options(parser, *, top: bool):
    """-v/--verbose and -q/--quiet on ``parser``. On a command's parser they default to
    SUPPRESS, so that an option given before the command is not reset by the command's parser;
    a command with its own -q/--quiet (progress off) keeps it, and main() reads both."""
    default = False if top else argparse.SUPPRESS
    if "-v" not in parser._option_string_actions:
        parser.add_argument("-v", "--verbose", action="store_true", default=default,
                            help=VERBOSE_HELP)
    if "-q" not in parser._option_string_actions:
        parser.add_argument("-q", "--quiet", dest="global_quiet", action="store_true",
                            default=default, help=QUIET_HELP)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="tissue", description=__doc__,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    _add_global_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=Parser)
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(f"tissue_reference.tissue.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"tissue_reference.tissue.{name}":
                continue
            raise
        mod.add_parser(sub)
    for command_parser in sub.choices.values():
        _add_global_options(command_parser, top=False)
    return parser


class _StderrHandler(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is when a record comes (in-process runs
    that replace stderr get their own records)."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, _):
        pass


# Loggers whose levels follow -v: the form compiler and the C toolchain it drives (the filter of
# fem_reference.logs shows setuptools'/distutils' gcc lines only at the level given to
# "tissue.compiler": none by default, so a first solve prints no compiler lines).
_COMPILER_LOGGERS = ("tissue.compiler", "FFCx", "ffcx")
_QUIET_LOGGERS = ("UFL", "matplotlib", "h5py", "PIL")   # third-party debug chatter


@contextlib.contextmanager
def logging_for(*, verbose: bool = False):
    """Logging for one command: records at WARNING and above (DEBUG with ``verbose``) to
    stderr, one line each; the C compiler's and the form compiler's chatter only with
    ``verbose``. The previous handlers and levels come back after the block."""
    level = logging.DEBUG if verbose else logging.WARNING
    root = logging.getLogger()
    names = ("tissue",) + _COMPILER_LOGGERS + _QUIET_LOGGERS
    saved = (root.level, {n: logging.getLogger(n).level for n in names})
    handler = _StderrHandler()
    handler.setLevel(level)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)
    root.setLevel(level)
    logging.getLogger("tissue").setLevel(level)
    for name in _COMPILER_LOGGERS:  # INFO: which forms are compiled, each gcc command line
        logging.getLogger(name).setLevel(logging.INFO if verbose else logging.WARNING)
    for name in _QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(saved[0])
        for name, lvl in saved[1].items():
            logging.getLogger(name).setLevel(lvl)


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
    except SystemExit as exc:  # --help / --version (0), or a bad option: its one line is printed
        return exc.code if isinstance(exc.code, int) else 2
    verbose = bool(getattr(args, "verbose", False))
    # -q/--quiet before the command, or after it (the command's own -q where it has one)
    quiet = bool(getattr(args, "global_quiet", False) or getattr(args, "quiet", False))
    args.quiet = quiet
    prog = f"tissue {args.command}"
    try:
        # the commands print what the Python API says as TissueWarning themselves
        with logging_for(verbose=verbose), warnings.catch_warnings():
            warnings.simplefilter("ignore", TissueWarning)
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
