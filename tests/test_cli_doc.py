"""The command-line reference is the parser's own output, and every option explains itself."""
from pathlib import Path

from tissue_reference.tissue.cli import build_parser
from tissue_reference.tissue.cli_doc import cli_markdown, options_without_help

ROOT = Path(__file__).resolve().parents[1]


def test_every_option_of_every_command_has_help():
    assert options_without_help(build_parser()) == []


def test_docs_cli_md_is_current():
    """docs/cli.md is tools/cli_doc.py's output; regenerate it after changing an option."""
    assert (ROOT / "docs" / "cli.md").read_text(encoding="utf-8") == cli_markdown()


def test_the_reference_lists_each_command_with_its_defaults():
    text = cli_markdown()
    for cmd in ("solve", "verify", "suite", "converge", "jacobian", "mpc", "table1", "demo"):
        assert f"## tissue {cmd}" in text
    assert "| `--solver` {fem, admm, mass-tensor} | fem |" in text
