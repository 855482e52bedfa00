"""Every command of the tutorial (docs/tutorial.md) and of the README runs as a
newcomer runs it: from a folder of their own outside the repository, with the shipped cases by
name, output folders made as needed and their own solver given as a file (the tutorial's
``my_solver.py``: here the repository's example plugin, which the tutorial names as one).

The commands are read from the documents, so a command edited there is the command tested. The
ones that take minutes at their documented discretization run with options appended that make
them small (argparse keeps the last value of an option): the same names, paths, solvers and
outputs are resolved, on fewer unknowns or steps (``SMALLER``; the documents state the full runs'
figures, measured by hand). Each must exit with status 0 and write the outputs it names."""
import re
import shlex
import shutil
from pathlib import Path

import pytest

from tissue_reference.tissue.cli import main

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
README = ROOT / "README.md"

# (command, case) -> options appended to make the run small
SMALLER = {
    ("solve", "phantom-indenter-quarter"): ["--degree", "1", "--no-estimate"],
    ("suite", None): ["--problems", "uniaxial-stretch"],
    ("mpc", "phantom-indenter-control"): ["--steps", "2"],
    ("table1", "phantom"): ["--size", "14", "--targets", "T1", "--steps", "4",
                            "--scenarios", "gravity"],
}


def _sh_blocks(text: str) -> list[str]:
    return re.findall(r"```sh\n(.*?)```", text, flags=re.DOTALL)


def _commands(block: str, prefix: str) -> list[list[str]]:
    """The ``prefix ...`` command lines of a shell block (continuations joined, comments cut)."""
    out = []
    for line in block.replace("\\\n", " ").splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith(prefix + " "):
            out.append(shlex.split(line)[1:])
    return out


def tutorial_commands() -> list[list[str]]:
    return [c for b in _sh_blocks(TUTORIAL.read_text()) for c in _commands(b, "tissue")]


def readme_commands() -> list[list[str]]:
    return [c for b in _sh_blocks(README.read_text()) for c in _commands(b, ".venv/bin/tissue")]


def _smaller(argv: list[str]) -> list[str]:
    case = argv[1] if len(argv) > 1 and not argv[1].startswith("-") else None
    return argv + SMALLER.get((argv[0], case), [])


def _named_outputs(argv: list[str]) -> list[str]:
    return [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("--out", "--json")]


def test_the_documents_hold_the_commands_this_test_runs():
    tut, rd = tutorial_commands(), readme_commands()
    assert [c[0] for c in tut] == ["solve", "solve", "converge", "verify", "verify", "suite",
                                   "jacobian", "mpc", "table1"]
    assert [c[0] for c in rd] == ["solve", "verify"]
    # every reduction applies to a command the documents hold
    held = {(c[0], c[1] if len(c) > 1 and not c[1].startswith("-") else None) for c in tut + rd}
    assert set(SMALLER) <= held


@pytest.fixture
def newcomer(tmp_path, monkeypatch):
    """A folder of the user's own with their solver file in it, as the current directory."""
    shutil.copy(ROOT / "examples" / "linear_plugin.py", tmp_path / "my_solver.py")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("where", ["tutorial", "readme"])
def test_each_documented_command_runs_from_a_folder_outside_the_repository(where, newcomer,
                                                                             capsys):
    commands = tutorial_commands() if where == "tutorial" else readme_commands()
    for argv in commands:
        run = _smaller(argv)
        status = main(run)
        out = capsys.readouterr()
        assert status == 0, (run, out.err[-2000:])
        for path in _named_outputs(argv):
            assert (newcomer / path).exists(), (run, path)
