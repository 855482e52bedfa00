"""The ``tissue`` command line follows the usual conventions: ``--version``,
``python -m tissue_reference``, global -v/--verbose and -q/--quiet before or after the command,
and a quiet first run (no C compiler lines while forms are compiled, unless -v)."""
import logging
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from test_cli_fuzz import BOX as CLI_BOX  # the small box case of the CLI tests

from tissue_reference.tissue.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
BOX = CLI_BOX.format(model="neo-hookean")


def project_version() -> str:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["project"]["version"]


def run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture
def box(tmp_path):
    p = tmp_path / "box.toml"
    p.write_text(BOX)
    return p


# --------------------------------------------------------------------------- version, -m
def test_version_is_the_package_version(capsys):
    rc, out, err = run(["--version"], capsys)
    assert rc == 0 and err == ""
    assert out.strip() == f"tissue {project_version()}"


def test_python_dash_m_tissue_runs_the_command_line():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, "-m", "tissue_reference", "--version"],
                       capture_output=True, text=True, timeout=120, check=False, cwd=ROOT, env=env)
    assert p.returncode == 0 and p.stdout.strip() == f"tissue {project_version()}", p.stderr
    p = subprocess.run([sys.executable, "-m", "tissue_reference", "mesh", "--bogus"],
                       capture_output=True, text=True, timeout=120, check=False, cwd=ROOT, env=env)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.startswith("tissue mesh: error:"), p.stderr


# --------------------------------------------------------------------------- global options
@pytest.mark.parametrize("argv", [
    ["-v", "mesh", "box", "-o", "m.vtu"],
    ["mesh", "-v", "box", "-o", "m.vtu"],
    ["mesh", "box", "-o", "m.vtu", "--verbose"],
])
def test_verbose_is_accepted_before_or_after_the_command(argv):
    args = build_parser().parse_args(argv)
    assert args.command == "mesh" and args.verbose is True


@pytest.mark.parametrize("argv, global_quiet, own_quiet", [
    (["-q", "mesh", "box", "-o", "m.vtu"], True, None),
    (["mesh", "box", "-o", "m.vtu", "-q"], True, None),
    (["mesh", "box", "-o", "m.vtu", "--quiet"], True, None),
    (["-q", "solve", "c.toml"], True, False),        # solve has its own -q (progress off)
    (["solve", "c.toml", "-q"], False, True),
    (["--quiet", "solve", "c.toml", "--quiet"], True, True),
    (["solve", "c.toml"], False, False),
])
def test_quiet_is_accepted_before_or_after_the_command(argv, global_quiet, own_quiet):
    args = build_parser().parse_args(argv)
    assert getattr(args, "global_quiet", False) is global_quiet
    assert getattr(args, "quiet", None) is own_quiet
    assert getattr(args, "verbose", False) is False


def test_every_command_takes_the_global_options():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "solve" in a.choices)
    for name, command in sub.choices.items():
        assert {"-v", "--verbose", "-q", "--quiet"} <= set(command._option_string_actions), name


@pytest.mark.parametrize("where", ["before", "after"])
def test_quiet_turns_progress_off_wherever_it_is_given(box, tmp_path, capsys, where):
    argv = ["solve", box, "--push", "A1=1", "--json", tmp_path / "r.json"]
    rc, out, err = run(argv, capsys)
    assert rc == 0 and "newton" in err            # progress lines by default
    argv = ["-q", *argv] if where == "before" else [*argv, "-q"]
    rc, out, err = run(argv, capsys)
    # no progress; warnings about the answer (its estimated error here) are not progress
    assert rc == 0 and "converged=True" in out and "newton" not in err
    assert all(line.startswith("tissue solve: warning:") for line in err.splitlines()), err


def test_verbose_shows_debug_records_and_the_default_shows_warnings(monkeypatch, tmp_path,
                                                                     capsys):
    from tissue_reference.tissue import cmd_mesh

    def fake_run(args):
        log = logging.getLogger("tissue.mesh")
        log.debug("a debug record")
        log.warning("a warning record")
        return 0

    monkeypatch.setattr(cmd_mesh, "run", fake_run)
    rc, _, err = run(["mesh", "box", "-o", tmp_path / "m.vtu"], capsys)
    assert rc == 0 and "a warning record" in err and "a debug record" not in err
    rc, _, err = run(["mesh", "box", "-o", tmp_path / "m.vtu", "-v"], capsys)
    assert rc == 0 and "DEBUG tissue.mesh: a debug record" in err and "a warning record" in err
    # the command's logging is undone afterwards: no handler of it is left on the root logger
    assert not [h for h in logging.getLogger().handlers if type(h).__name__ == "_StderrHandler"]


# --------------------------------------------------------------------------- compiler lines
def toolchain_record(level=logging.INFO):
    """A record as setuptools/distutils log a gcc command line: on the root logger, from a
    module of setuptools' distutils."""
    import setuptools

    path = str(Path(setuptools.__file__).parent / "_distutils" / "spawn.py")
    return logging.LogRecord("root", level, path, 1, "x86_64-linux-gnu-gcc -c form.c", None,
                             None)


def test_the_compiler_filter_drops_toolchain_records_unless_asked_for():
    from tissue_reference.fem_reference.logs import CompilerLogFilter

    f = CompilerLogFilter()
    assert any(isinstance(x, CompilerLogFilter) for x in logging.getLogger().filters)
    compiler = logging.getLogger("tissue.compiler")
    saved = compiler.level
    try:
        compiler.setLevel(logging.NOTSET)
        assert not f.filter(toolchain_record())
        compiler.setLevel(logging.WARNING)
        assert not f.filter(toolchain_record())
        assert f.filter(toolchain_record(logging.WARNING))     # warnings always pass
        compiler.setLevel(logging.DEBUG)                        # tissue -v
        assert f.filter(toolchain_record())
    finally:
        compiler.setLevel(saved)
    own = logging.LogRecord("root", logging.INFO, __file__, 1, "a record of our own", None, None)
    assert f.filter(own)
    assert f.filter(logging.LogRecord("tissue.fem", logging.INFO, __file__, 1, "x", None, None))
    assert not f.filter(logging.LogRecord("setuptools.dist", logging.INFO, __file__, 1, "x",
                                          None, None))


@pytest.mark.slow
def test_a_first_solve_prints_no_compiler_lines_and_verbose_shows_them(tmp_path):
    """A fresh FFCx cache: every form is compiled with gcc in this run."""
    tissue = str(Path(sys.executable).with_name("tissue"))
    argv = [tissue, "solve", "meshes/cases/phantom.toml", "--size", "14", "--push", "A1=2"]
    outputs = {}
    for flag in ("", "-v"):
        env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / f"cache{flag}"))
        p = subprocess.run(argv + ([flag] if flag else []), capture_output=True, text=True,
                           timeout=600, check=False, cwd=ROOT, env=env)
        assert p.returncode == 0, p.stderr
        assert any((tmp_path / f"cache{flag}").rglob("libffcx_forms_*.c")), "nothing compiled"
        outputs[flag] = p
    quiet = outputs[""]
    assert "gcc" not in quiet.stdout + quiet.stderr and "build_ext" not in quiet.stderr, \
        quiet.stderr
    assert quiet.stdout.startswith("phantom: fem converged=True")
    assert all(line.startswith(("  load", "tissue fem:", "tissue solve: warning:",
                                "tissue solve: meshed"))
               for line in quiet.stderr.splitlines())
    verbose = outputs["-v"]
    assert "INFO root: running build_ext" in verbose.stderr and "gcc" in verbose.stderr
    assert "gcc" not in verbose.stdout
    def answer(out):  # the summary without its timings
        return [line for line in out.splitlines()[1:] if "cost" not in line]

    assert answer(verbose.stdout) == answer(quiet.stdout)  # same answer


def test_quiet_silences_the_progress_of_a_convergence_study(box, tmp_path, capsys):
    argv = ["converge", box, "--levels", "3", "--degrees", "1", "--push", "A1=1", "--json",
            tmp_path / "c.json"]
    rc, out, err = run(argv, capsys)
    assert rc == 0 and err.count("tissue converge: degree 1, level") == 3
    rc, out, err = run(["-q", *argv], capsys)
    assert rc == 0 and "tissue converge:" not in err and "level" in out   # the table stays


def test_quiet_silences_the_progress_of_the_table1_runs(monkeypatch):
    """The Table I command hands a no-op progress callback to its runs under -q."""
    from types import SimpleNamespace

    from tissue_reference.tissue import cmd_table1

    lines = []
    monkeypatch.setattr("builtins.print", lambda *a, **k: lines.append(a))
    cmd_table1._progress(SimpleNamespace(quiet=True))("a line")
    assert lines == []
    cmd_table1._progress(SimpleNamespace(quiet=False))("a line")
    assert lines == [("a line",)]
