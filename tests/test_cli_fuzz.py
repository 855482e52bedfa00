"""Bad input at the command line never crashes and never silently lies: a command-line fuzz of
malformed options, values, files and output paths run in-process through ``tissue.cli.main``
(a few through the installed ``tissue`` script), each answered with exit status 2 and one line
naming the option or file and the value, and no traceback; outputs are checked before any work
and written whole or not at all, also when the run is interrupted."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tissue_reference.meshes.builders import estimate_cells
from tissue_reference.meshes.io import atomic_path
from tissue_reference.tissue.cli import main

BOX = """name = "box"
[mesh]
builtin = "box"
size = 5.0
[material]
model = "{model}"
E = 6.0
nu = 0.45
[[boundary]]
region = "xmin"
type = "fixed"
[[actuator]]
name = "A1"
region = "xmax"
direction = [-1.0, 0.0, 0.0]
[[probe]]
name = "T1"
point = [5.0, 5.0, 5.0]
"""


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    (d / "box.toml").write_text(BOX.format(model="neo-hookean"))
    (d / "lin.toml").write_text(BOX.format(model="linear-elastic"))
    (d / "folder.toml").mkdir()
    (d / "binary.toml").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    (d / "a_file").write_text("x")
    (d / "out_dir").mkdir()
    (d / "skin.stl").mkdir()
    return d


def run(argv, capsys):
    """(exit status, stdout, stderr) of ``tissue argv`` in-process."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # main returns; a SystemExit would be a bug, reported as such
        rc = ("SystemExit", exc.code)
    out, err = capsys.readouterr()
    return rc, out, err


def unwritable_dir(base: Path) -> Path:
    """A folder this process cannot create files in (root: /sys, which refuses even root)."""
    if os.geteuid() == 0:
        return Path("/sys")
    d = base / "read_only"
    d.mkdir(exist_ok=True)
    d.chmod(0o555)
    return d


# --------------------------------------------------------------------------- the inputs
REAL_BAD = {
    "positive": ["abc", "nan", "inf", "-inf", "-1", "0", "1e400", "", "1,5"],
    "nonneg": ["abc", "nan", "inf", "-1", "-1e-9"],
    "finite": ["abc", "nan", "inf", "-inf", "1e999"],
    "int1": ["abc", "1.5", "0", "-3", "nan"],
}
# (command and its other arguments, option, kind); CASE / OUT are filled in per test
OPTIONS = [
    (["solve", "CASE"], "--size", "positive"),
    (["solve", "CASE"], "--max-cells", "int1"),
    (["mesh", "box", "-o", "OUT/m.msh"], "--size", "positive"),
    (["mesh", "box", "-o", "OUT/m.msh"], "--max-cells", "int1"),
    (["verify", "CASE"], "--stop-mm", "positive"),
    (["converge", "CASE"], "--size", "positive"),
    (["converge", "CASE"], "--max-cells", "int1"),
    (["jacobian", "CASE"], "--fd-h", "nonneg"),
    (["mpc", "CASE", "--target", "T1", "--task", "1"], "--model-E-factor", "positive"),
    (["mpc", "CASE", "--target", "T1", "--task", "1"], "--model-size", "positive"),
    (["mpc", "CASE", "--target", "T1", "--task", "1"], "--noise", "nonneg"),
    (["mpc", "CASE", "--target", "T1", "--task", "1"], "--steps", "int1"),
    (["mpc", "CASE", "--target", "T1", "--task", "1"], "--dt", "positive"),
    (["mpc", "CASE", "--target", "T1", "--task", "1"], "--horizon", "int1"),
    (["mpc", "CASE", "--target", "T1", "--task", "1"], "--q", "positive"),
    (["table1", "CASE", "--out", "OUT/t"], "--r", "positive"),
    (["table1", "CASE", "--out", "OUT/t"], "--max-travel", "positive"),
    (["manipulability", "CASE", "--out", "OUT/m"], "--plane-z", "finite"),
    (["manipulability", "CASE", "--out", "OUT/m"], "--spacing", "positive"),
    (["implant", "--synthetic", "--json", "OUT/i.json"], "--volume", "positive"),
    (["implant", "--synthetic", "--json", "OUT/i.json"], "--width", "positive"),
    (["implant", "--synthetic", "--json", "OUT/i.json"], "--free-ring", "nonneg"),
    (["demo", "--out", "OUT/demo"], "--size", "positive"),
    (["demo", "--out", "OUT/demo"], "--verify-push", "positive"),
    (["demo", "--out", "OUT/demo"], "--verify-size", "positive"),
    (["demo", "--out", "OUT/demo"], "--pushes", "positive"),
]
BAD_NUMBERS = [(cmd, opt, v) for cmd, opt, kind in OPTIONS for v in REAL_BAD[kind]]


def fill(argv, work, case="box.toml"):
    return [str(work / case) if a == "CASE" else a.replace("OUT", str(work)) for a in argv]


def assert_refused(rc, err, *names):
    assert rc == 2, (rc, err)
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for name in names:
        assert str(name) in lines[0], (name, err)


@pytest.mark.parametrize("cmd,opt,value", BAD_NUMBERS,
                         ids=[f"{c[0]}{o}={v!r}" for c, o, v in BAD_NUMBERS])
def test_a_bad_number_exits_2_naming_the_option_and_value(work, capsys, cmd, opt, value):
    rc, _, err = run(fill(cmd, work) + [f"{opt}={value}"], capsys)
    assert_refused(rc, err, opt, repr(value))
    assert not (work / "m.msh").exists() and not (work / "t").exists()


MULTI = [
    (["implant", "--synthetic", "--json", "OUT/i.json", "--at", "1", "nan"], "--at", "'nan'"),
    (["implant", "--skin", "OUT/a_file", "--json", "OUT/i.json", "--thickness", "10", "nan", "10"],
     "--thickness", "'nan'"),
    (["implant", "--synthetic", "--json", "OUT/i.json", "--thickness-x", "0", "inf", "1"],
     "--thickness-x", "'inf'"),
    (["solve", "CASE", "--solver", "fast"], "--solver", "'fast'"),
    (["solve", "CASE", "--degree", "4"], "--degree", "invalid choice: 4"),
    (["mpc", "CASE", "--target", "T1", "--task", "4"], "--task", "invalid choice: 4"),
    (["mpc", "CASE", "--target", "T1", "--task", "1", "--seed", "-1"], "--seed", "'-1'"),
    (["converge", "CASE", "--levels", "2"], "--levels", "at least 3 meshes"),
    (["solve", "CASE", "--sise", "3"], "--sise", "did you mean --size?"),
    (["solve", "CASE", "--push", "A1", "15"], "15", "did you mean --push A1=15?"),
    (["solve"], "case", "required"),
    (["explode", "CASE"], "explode", "invalid choice"),
]


@pytest.mark.parametrize("argv,opt,value", MULTI, ids=[" ".join(m[0][:4]) for m in MULTI])
def test_malformed_command_lines_exit_2_in_one_line(work, capsys, argv, opt, value):
    rc, _, err = run(fill(argv, work), capsys)
    assert_refused(rc, err, opt, value)


PUSHES = [
    ("A1", "NAME=MM"), ("A1=abc", "'A1=abc'"), ("A1=nan", "'nan'"), ("A1=inf", "'inf'"),
    ("A1=-inf", "'-inf'"), ("=5", "'=5'"), ("A9=1", "unknown actuator 'A9'"),
    ("A1=1e308", "1e+308"), ("A1=-500", "-500"), ("A1=1e6", "1e+06"),
]


@pytest.mark.parametrize("cmd", ["solve", "verify"])
@pytest.mark.parametrize("push,shown", PUSHES, ids=[p[0] for p in PUSHES])
def test_a_bad_push_exits_2_naming_it(work, capsys, cmd, push, shown):
    rc, _, err = run([cmd, work / "box.toml", "--push", push, "--json", work / "p.json"], capsys)
    assert_refused(rc, err, "--push", shown)
    assert not (work / "p.json").exists()


def test_a_push_given_twice_is_refused_not_overwritten(work, capsys):
    rc, _, err = run(["solve", work / "box.toml", "--push", "A1=1", "--push", "A1=2"], capsys)
    assert_refused(rc, err, "--push", "'A1' is given twice", "1", "2")


@pytest.mark.parametrize("push,shown", [("A9=1", "'A9'"), ("A1=nan", "'nan'"),
                                        ("A1=1e300", "1e+300"), ("A1", "NAME=MM")])
def test_a_bad_state_push_or_fd_step_is_named(work, capsys, push, shown):
    rc, _, err = run(["jacobian", work / "box.toml", "--state-push", push], capsys)
    assert_refused(rc, err, "--state-push", shown)
    rc, _, err = run(["jacobian", work / "box.toml", "--fd-h", "1e5"], capsys)
    assert_refused(rc, err, "--fd-h", "100000")


CASE_FILES = [
    ("missing.toml", None, "does not exist"),
    ("folder.toml", None, "is a directory"),
    ("binary.toml", None, "not UTF-8"),
    ("tiny.toml", BOX.format(model="neo-hookean").replace("size = 5.0", "size = 0.01"),
     f"about {estimate_cells('box', 0.01):,} cells"),
    ("soft.toml", BOX.format(model="neo-hookean").replace("E = 6.0", "E = 1e-300"), "1e-300"),
    ("hard.toml", BOX.format(model="neo-hookean").replace("E = 6.0", "E = 1e300"), "1e+300"),
    ("far.toml", BOX.format(model="neo-hookean").replace("[5.0, 5.0, 5.0]", "[1e308, 0.0, 0.0]"),
     "1e+308"),
    ("nomesh.toml", '[mesh]\nfile = "nowhere.msh"\n', "nowhere.msh"),
]


@pytest.mark.parametrize("name,text,shown", CASE_FILES, ids=[c[0] for c in CASE_FILES])
@pytest.mark.parametrize("cmd", [["solve"], ["verify"], ["jacobian"],
                                 ["mpc", "--target", "T1", "--task", "1"]])
def test_a_bad_case_file_exits_2_naming_the_file(work, capsys, name, text, shown, cmd):
    if text is not None:
        (work / name).write_text(text)
    rc, _, err = run([cmd[0], work / name, *cmd[1:]], capsys)
    assert rc == 2 and "Traceback" not in err, err
    assert name in err and shown in err, err


def test_a_size_override_above_the_cell_limit_is_refused_with_the_estimate(work, capsys):
    rc, _, err = run(["solve", work / "box.toml", "--size", "0.05"], capsys)
    assert_refused(rc, err, "box.toml", "0.05 mm", f"about {estimate_cells('box', 0.05):,} cells",
                   "--max-cells")
    rc, _, err = run(["mesh", "phantom", "--size", "0.3", "-o", work / "p.msh"], capsys)
    assert_refused(rc, err, "0.3 mm", "cells", "2,000,000")
    assert not (work / "p.msh").exists()
    # --max-cells lowers (or raises) the limit
    rc, _, err = run(["mesh", "box", "--size", "1", "--max-cells", "1000", "-o", work / "b.msh"],
                     capsys)
    assert_refused(rc, err, f"about {estimate_cells('box', 1.0):,} cells", "1,000")


def test_a_large_build_announces_its_estimate_before_meshing(work, capsys):
    rc, _, err = run(["mesh", "box", "--size", "0.3", "--max-cells", "100",
                      "-o", work / "b.msh"], capsys)
    assert rc == 2 and f"about {estimate_cells('box', 0.3):,} cells" in err


def output_mistakes(work):
    ro = unwritable_dir(work)
    return [
        (["solve", "CASE", "--json", "OUT/out_dir"], "--json", "is a directory"),
        (["solve", "CASE", "--json", "OUT/out_dir/"], "--json", "is a directory"),
        (["solve", "CASE", "--json", "OUT/a_file/x.json"], "--json", "is not a folder"),
        (["solve", "CASE", "--json", f"{ro}/x.json"], "--json", "not writable"),
        (["solve", "CASE", "--json", "OUT/a_file/deeper/x.json"], "--json", "is not a folder"),
        (["solve", "CASE", "--out", "OUT/a_file/fields"], "--out", "is not a folder"),
        (["solve", "CASE", "--out", f"{ro}/missing/fields"], "--out", "not writable"),
        (["solve", "CASE", "--out", "OUT/a_file"], "--out", "is a file"),
        (["solve", "CASE", "--out", f"{ro}/fields"], "--out", "not writable"),
        (["verify", "CASE", "--json", "OUT/out_dir"], "--json", "is a directory"),
        (["verify", "CASE", "--out", "OUT/a_file"], "--out", "is a file"),
        (["converge", "CASE", "--json", "OUT/out_dir"], "--json", "is a directory"),
        (["jacobian", "CASE", "--json", "OUT/a_file/j.json"], "--json", "is not a folder"),
        (["mpc", "CASE", "--target", "T1", "--task", "1", "--json", "OUT/out_dir"], "--json",
         "is a directory"),
        (["table1", "CASE", "--out", "OUT/a_file"], "--out", "is a file"),
        (["manipulability", "CASE", "--out", f"{ro}/maps"], "--out", "not writable"),
        (["implant", "--synthetic", "--json", "OUT/out_dir"], "--json", "is a directory"),
        (["implant", "--skin", "OUT/nowhere.stl", "--thickness", "1", "2", "3", "--json",
          "OUT/i.json"], "--skin", "does not exist"),
        (["implant", "--skin", "OUT/skin.stl", "--thickness", "1", "2", "3", "--json",
          "OUT/i.json"], "--skin", "is a directory"),
        (["demo", "--out", "OUT/a_file"], "--out", "is a file"),
        (["mesh", "box", "-o", "OUT/out_dir"], "-o", "is a directory"),
        (["mesh", "box", "-o", "OUT/m.stl"], "-o", "unsupported suffix '.stl'"),
        (["mesh", "box", "-o", f"{ro}/m.msh"], "-o", "not writable"),
    ]


def test_output_paths_are_refused_before_any_work(work, capsys, monkeypatch):
    import tissue_reference.meshes.builders
    import tissue_reference.meshes.builders_gmsh
    meshes = tissue_reference.meshes

    def no_meshing(*a, **k):
        raise AssertionError("meshed before the output check")

    # the builders open the session from builders_gmsh; implant's geometry from meshes.builders
    monkeypatch.setattr(meshes.builders_gmsh, "gmsh_session", no_meshing)
    monkeypatch.setattr(meshes.builders, "gmsh_session", no_meshing)
    for argv, opt, why in output_mistakes(work):
        rc, _, err = run(fill(argv, work), capsys)
        assert_refused(rc, err, opt, why)
    hidden = [p for p in work.rglob(".*")]
    assert hidden == [], hidden


def test_mistakes_in_the_installed_script_give_one_line_and_no_traceback(work):
    tissue = str(Path(sys.executable).with_name("tissue"))
    for argv, shown in [(["solve", work / "box.toml", "--size", "abc"], "'abc'"),
                        (["solve", work / "box.toml", "--json", work / "out_dir"], "out_dir"),
                        (["mesh", "box", "-o", work / "a_file" / "m.msh"], "a_file")]:
        p = subprocess.run([tissue, *map(str, argv)], capture_output=True, text=True, timeout=120,
                           check=False)
        assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1 and shown in p.stderr, p.stderr


# --------------------------------------------------------------------------- answers
def test_a_valid_answer_exits_0_and_an_invalid_one_exits_1_with_marked_outputs(work, capsys):
    import json

    rc, _, err = run(["solve", work / "lin.toml", "--solver", "mass-tensor", "--push", "A1=1",
                        "-q", "--json", work / "ok.json"], capsys)
    assert rc == 0 and err == "", err
    d = json.loads((work / "ok.json").read_text())
    assert d["valid"] is True and d["inverted_cells"] == 0 and 0 < d["min_J"] < 1.2
    rc, _, err = run(["solve", work / "lin.toml", "--solver", "mass-tensor", "--push", "A1=9",
                        "-q", "--json", work / "bad.json", "--out", work / "bad"], capsys)
    assert rc == 1 and "Traceback" not in err
    assert "not valid" in err and "inverted cell" in err, err
    d = json.loads((work / "bad.json").read_text())
    assert d["valid"] is False and d["inverted_cells"] > 0 and d["min_J"] <= 0
    assert d["converged"] is True          # the solver's own verdict is kept
    assert (work / "bad" / "displacement.vtu").is_file()


# --------------------------------------------------------------------------- interrupts
def leftovers(folder: Path):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_an_interrupted_solve_leaves_no_output(tmp_path, capsys, monkeypatch):
    import tissue_reference.tissue.cmd_solve as cmd

    (tmp_path / "lin.toml").write_text(BOX.format(model="linear-elastic"))
    real = cmd.run_solver

    def interrupt(it, u):   # at the solver's first iteration (its direct solve has one)
        raise KeyboardInterrupt

    monkeypatch.setattr(cmd, "run_solver", lambda *a, **k: real(*a, callback=interrupt, **k))
    rc, _, err = run(["solve", tmp_path / "lin.toml", "--solver", "mass-tensor", "--push",
                      "A1=1", "-q", "--json", tmp_path / "r.json", "--out", tmp_path / "f"],
                     capsys)
    assert rc == 130 and "interrupted" in err and "Traceback" not in err
    assert leftovers(tmp_path) == ["lin.toml"]


def test_an_interrupt_while_writing_leaves_whole_files_and_no_temporaries(tmp_path, capsys,
                                                                          monkeypatch):
    import meshio

    (tmp_path / "lin.toml").write_text(BOX.format(model="linear-elastic"))
    real = meshio.write

    def write(path, mesh, file_format=None, **kw):
        if file_format == "vtu":
            Path(path).write_text("partial")
            raise KeyboardInterrupt
        return real(path, mesh, file_format=file_format, **kw)

    monkeypatch.setattr(meshio, "write", write)
    rc, _, _ = run(["solve", tmp_path / "lin.toml", "--solver", "mass-tensor", "--push",
                    "A1=1", "-q", "--json", tmp_path / "r.json", "--out", tmp_path / "f"], capsys)
    assert rc == 130
    # the XDMF pair was complete before the interrupt; no .vtu, no JSON, no temporary
    assert leftovers(tmp_path) == ["f", "f/displacement.h5", "f/displacement.xdmf", "lin.toml"]


@pytest.mark.parametrize("error", [KeyboardInterrupt, ValueError, SystemExit])
def test_atomic_path_removes_its_temporary_on_any_exception(tmp_path, error):
    with pytest.raises(error), atomic_path(tmp_path / "a.json") as tmp:
        tmp.write_text("half")
        raise error
    assert leftovers(tmp_path) == []


def test_atomic_path_onto_a_directory_is_a_write_error_without_temporaries(tmp_path):
    from tissue_reference.errors import WriteError

    (tmp_path / "d").mkdir()
    with pytest.raises(WriteError, match="is a directory"), atomic_path(tmp_path / "d") as tmp:
        tmp.write_text("x")
    assert leftovers(tmp_path) == ["d"]
