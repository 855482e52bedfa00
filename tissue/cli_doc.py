"""The command-line reference (docs/cli.md) rendered from the parser itself, so that it cannot
drift from what the commands accept: every command, its options, their defaults and help."""
from __future__ import annotations

import argparse

from .cli import build_parser

__all__ = ["cli_markdown", "options_without_help"]

EXIT_CODES = """Exit status (every command): 0 done; 1 an answer was computed but is not valid
(inverted cells, runaway growth, a tip through the skin), a tolerance was not met (`verify
--tol`, `suite --strict`, `solve --accuracy` at `--max-dofs`), or a load or loop went past the
range where answers converge (a glued patch past its radius, a tip past 2.5 radii: `solve`,
`verify`, `mpc`, `table1`): the outputs are written and marked; 2 an error named in one line: bad input (an option, a case or mesh file, an output
path) or a failure during the work (a solve that does not converge, its last converged state
written first; a fast solver that diverges; an `mpc` goal out of reach); 130 interrupted.
Details: docs/outputs.md."""


def _commands(parser):
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in sub._choices_actions}
    return [(name, helps.get(name, ""), p) for name, p in sub.choices.items()]


def _options(p):
    return [a for a in p._actions if not isinstance(a, argparse._HelpAction)]


def options_without_help(parser) -> list:
    """(command, option) of every option that has no help text."""
    return [(name, "/".join(a.option_strings) or a.dest) for name, _, p in _commands(parser)
            for a in _options(p) if not a.help or a.help == argparse.SUPPRESS]


def _default(a) -> str:
    if a.required or isinstance(a, argparse._StoreTrueAction) or a.default in (None,
                                                                               argparse.SUPPRESS):
        return "required" if a.required else ""
    d = a.default
    return " ".join(map(str, d)) if isinstance(d, (list, tuple)) else str(d)


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def cli_markdown(parser=None) -> str:
    """docs/cli.md as text."""
    if parser is None:
        parser = build_parser()
    out = ["<!-- generated from the tissue parser by tools/cli_doc.py; do not edit -->", "",
           "# Command-line reference", "",
           ("`tissue COMMAND [options]` (or `python -m tissue_reference`); `tissue --version`. "
            "Global options, before or after the command: `-v/--verbose`, `-q/--quiet`."), "",
           EXIT_CODES, ""]
    for name, help_, p in _commands(parser):
        out += [f"## tissue {name}", "", _cell(help_), "", "| option | default | meaning |",
                "|---|---|---|"]
        for a in _options(p):
            names = ", ".join(f"`{o}`" for o in a.option_strings) or f"`{a.dest}` (positional)"
            if a.choices:
                names += " {" + ", ".join(map(str, a.choices)) + "}"
            out.append(f"| {_cell(names)} | {_cell(_default(a))} | {_cell(a.help or '')} |")
        out.append("")
    return "\n".join(out)
