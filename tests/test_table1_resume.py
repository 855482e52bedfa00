"""Resuming a Table I run: a run stopped after its first loop, run again in its folder, runs only
the loops it lacks and ends with the table of a run never stopped; a folder of other settings and
a file that is not such a table are refused by name and left byte for byte as they were. The
loops run on a linear P1 plant (``test_control_support``), a few steps each: seconds in all."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from test_control_support import LinearPlant, linear_p1_stiffness, linear_tangent, phantom

from tissue_reference.control.loop import LoopSettings
from tissue_reference.control.plants import build_loop
from tissue_reference.control.table1 import run_table1
from tissue_reference.errors import CaseError, CaseReadError

STEPS = 6
RTOL, ATOL = 1e-9, 1e-12
"""How close a resumed table's numbers are to those of a run never stopped: the same loops on
the same linear plant, so equal but for round-off."""


def linear_loop(case):
    """A ``control.plants.LoopSetup`` of ``case`` (its meta as the command line's) whose plant
    and model are the linear P1 plant: a loop of a few steps in a fraction of a second."""
    K = linear_p1_stiffness(case)
    return replace(build_loop(case), plant=LinearPlant(K), model_solve=LinearPlant(K),
                   model_tangent=linear_tangent(K), fast_model=False, model_sensitivity=None)


class Stopping:
    """A loop that is stopped (KeyboardInterrupt, as Ctrl-C) when it starts its loop number
    ``after`` + 1; ``ran`` lists the (target, task) of the loops it ran."""

    def __init__(self, loop, after=None):
        self.loop, self.after, self.ran = loop, after, []
        self.meta = loop.meta

    def run(self, target, task, settings, progress=None):
        if self.after is not None and len(self.ran) >= self.after:
            raise KeyboardInterrupt
        self.ran.append((target, task))
        return self.loop.run(target, task, settings, progress)


@pytest.fixture(scope="module")
def case():
    # linear elastic: so is the plant (its answers then have no push range)
    return phantom().with_material(model="linear-elastic")


def rows_of(folder):
    return json.loads((folder / "table1.json").read_text())["rows"]


def assert_same_rows(rows, expected):
    """Equal keys, equal words, numbers within RTOL / ATOL; timings (``*_s``, ``*_ms``) aside."""
    assert [(r["target"], r["task"]) for r in rows] == [(r["target"], r["task"]) for r in expected]
    for row, exp in zip(rows, expected):
        assert set(row) == set(exp)
        for key in row:
            if key.endswith(("_s", "_ms")):
                continue
            a, b = row[key], exp[key]
            if isinstance(a, (dict, str, bool)) or a is None or isinstance(a, list) and (
                    not a or not isinstance(np.ravel(np.asarray(a, dtype=object))[0],
                                            (int, float))):
                assert a == b, key
            else:
                np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float),
                                           rtol=RTOL, atol=ATOL, err_msg=key)


def test_a_run_stopped_after_its_first_loop_resumes_to_the_table_of_a_run_never_stopped(
        case, tmp_path):
    settings = LoopSettings(steps=STEPS)
    whole = Stopping(linear_loop(case))
    summ = run_table1(case, ["T1"], whole, settings, tmp_path / "whole", plots=False,
                      progress=lambda line: None)
    assert whole.ran == [("T1", 1), ("T1", 2), ("T1", 3)] and summ["ran"] == 3

    out = tmp_path / "stopped"
    with pytest.raises(KeyboardInterrupt):
        run_table1(case, ["T1"], Stopping(linear_loop(case), after=1), settings, out,
                   plots=False, progress=lambda line: None)
    assert [(r["target"], r["task"]) for r in rows_of(out)] == [("T1", 1)]

    again, lines = Stopping(linear_loop(case)), []
    resumed = run_table1(case, ["T1"], again, settings, out, plots=False,
                         progress=lines.append, resume=True)
    assert again.ran == [("T1", 2), ("T1", 3)]   # only the loops the folder lacks
    assert lines[0] == (f"table1: resuming from {out / 'table1.json'}: 1 of 3 loops finished "
                        f"there, 2 to run; taken from it: T1 task 1")
    assert_same_rows(rows_of(out), rows_of(tmp_path / "whole"))
    assert {k: v for k, v in resumed.items() if k != "worst_closed_loop_sse_mm"} == \
        {k: v for k, v in summ.items() if k != "worst_closed_loop_sse_mm"}
    assert resumed["worst_closed_loop_sse_mm"] == pytest.approx(summ["worst_closed_loop_sse_mm"],
                                                                rel=RTOL, abs=ATOL)
    table = json.loads((out / "table1.json").read_text())
    assert table["meta"]["settings"]["steps"] == STEPS and table["meta"]["plant"] == "fem"

    done = Stopping(linear_loop(case))
    run_table1(case, ["T1"], done, settings, out, plots=False, progress=lambda line: None,
               resume=True)
    assert done.ran == []   # nothing left to run


def test_a_resume_with_other_settings_is_refused_naming_them_and_the_file_is_kept(case, tmp_path):
    out = tmp_path / "t"
    with pytest.raises(KeyboardInterrupt):
        run_table1(case, ["T1"], Stopping(linear_loop(case), after=1), LoopSettings(steps=STEPS),
                   out, plots=False, progress=lambda line: None)
    path = out / "table1.json"
    before = path.read_bytes()

    other = Stopping(linear_loop(case))
    with pytest.raises(CaseError) as err:
        run_table1(case, ["T1"], other, LoopSettings(steps=STEPS + 2, task_mm=0.5), out,
                   plots=False, progress=lambda line: None, resume=True)
    msg = str(err.value)
    assert str(path) in msg
    assert f"settings.steps ({STEPS} there, {STEPS + 2} now)" in msg
    assert "settings.task_mm (5.0 there, 0.5 now)" in msg
    assert "another --out folder" in msg and "delete the file" in msg
    stiffer = Stopping(linear_loop(case.with_material(E=2 * case.material.E)))
    with pytest.raises(CaseError, match=r"plant_material\.E_kPa"):
        run_table1(case, ["T1"], stiffer, LoopSettings(steps=STEPS), out, plots=False,
                   progress=lambda line: None, resume=True)
    with pytest.raises(CaseError, match=r"rows this run does not ask for \(T1 task 1\)"):
        run_table1(case, ["T2"], other, LoopSettings(steps=STEPS), out, plots=False,
                   progress=lambda line: None, resume=True)
    assert other.ran == [] and stiffer.ran == []
    assert path.read_bytes() == before


@pytest.mark.parametrize("text", [b"{", b"", b"\xff\xfe\x00", b"[]", b'{"rows": []}',
                                  b'{"meta": [], "rows": []}', b'{"meta": {}, "rows": {}}',
                                  b'{"meta": {}, "rows": [{"target": "T1", "task": 7}]}',
                                  b'{"meta": {}, "rows": [{"task": 1}]}'])
def test_a_file_that_is_no_table_is_refused_by_name_and_left_as_it_is(case, tmp_path, text):
    path = tmp_path / "table1.json"
    path.write_bytes(text)
    loop = Stopping(linear_loop(case))
    with pytest.raises(CaseReadError, match="not a Table I table to resume from") as err:
        run_table1(case, ["T1"], loop, LoopSettings(steps=STEPS), tmp_path, plots=False,
                   progress=lambda line: None, resume=True)
    assert str(path) in str(err.value)
    assert loop.ran == [] and path.read_bytes() == text


def test_tissue_table1_resumes_refuses_and_restarts(case, tmp_path, monkeypatch, capsys):
    """The command line: a run interrupted after its first loop (exit status 130) resumes,
    printing the loop it took from the folder; other settings (exit status 2) and a broken
    table (2) are refused, naming the setting or the file, and leave it as it was; --restart
    runs every loop again."""
    from tissue_reference.tissue import loop_options
    from tissue_reference.tissue.cli import main

    runs = {"after": None, "ran": []}

    def build(case_, **kw):   # the command's loop with the linear plant as plant and model
        loop = Stopping(linear_loop(case_), after=runs["after"])
        loop.ran = runs["ran"]
        loop.case, loop.model_case = case_, None
        return loop

    monkeypatch.setattr(loop_options, "build_loop", build)
    whole, out = tmp_path / "whole", tmp_path / "t"
    cmd = ["table1", "phantom", "--size", "12", "--material", "linear-elastic", "--targets",
           "T1", "--steps", str(STEPS), "-q", "--out"]
    assert main(cmd + [str(whole)]) == 0
    runs["after"], runs["ran"] = 1, []
    assert main(cmd + [str(out)]) == 130
    assert [r["task"] for r in rows_of(out)] == [1]
    capsys.readouterr()

    runs["after"], runs["ran"] = None, []
    assert main(cmd[:-2] + ["--out", str(out)]) == 0   # not quiet: says what it took
    assert runs["ran"] == [("T1", 2), ("T1", 3)]
    assert "1 of 3 loops finished there, 2 to run; taken from it: T1 task 1" in \
        capsys.readouterr().out
    assert_same_rows(rows_of(out), rows_of(whole))

    path = out / "table1.json"
    before = path.read_bytes()
    runs["ran"] = []
    assert main(cmd[:-3] + [str(STEPS + 1), "-q", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"settings.steps ({STEPS} there, {STEPS + 1} now)" in err and str(path) in err
    assert "--restart" in err and runs["ran"] == [] and path.read_bytes() == before

    path.write_bytes(before[:100])   # cut short
    assert main(cmd + [str(out)]) == 2
    err = capsys.readouterr().err
    assert "not a Table I table to resume from" in err and str(path) in err
    assert path.read_bytes() == before[:100] and runs["ran"] == []

    assert main(cmd + [str(out), "--restart"]) == 0
    assert runs["ran"] == [("T1", 1), ("T1", 2), ("T1", 3)]
    assert_same_rows(rows_of(out), rows_of(whole))


def test_tissue_table1_scenarios_resume_each_folder_and_refuse_before_any_loop(tmp_path, capsys):
    """--scenarios: each scenario's folder resumes as a table of its own; a scenario folder that
    cannot be resumed is refused before any scenario runs a loop (the box case, whose one
    actuator leaves task 2 out of reach: a loop each of a few steps on a coarse mesh)."""
    from test_cli_fuzz import BOX

    from tissue_reference.tissue.cli import main

    (tmp_path / "box.toml").write_text(BOX.format(model="neo-hookean"))
    out = tmp_path / "s"
    cmd = ["table1", str(tmp_path / "box.toml"), "--steps", "3", "--task-mm", "2", "-q",
           "--scenarios", "gravity", "--out", str(out)]
    assert main(cmd) == 0
    table = out / "gravity" / "table1.json"
    first = table.read_bytes()
    capsys.readouterr()
    assert main([a for a in cmd if a != "-q"]) == 0   # every loop taken from the folder
    assert "3 of 3 loops finished there, 0 to run; taken from it: T1 task 1, T1 task 2, " \
           "T1 task 3" in capsys.readouterr().out
    assert json.loads(table.read_text())["rows"] == json.loads(first)["rows"]

    broken = b'{"meta": {}, "rows": 3}'
    table.write_bytes(broken)
    assert main(cmd[:-3] + ["mesh", "gravity", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "not a Table I table to resume from" in err and str(table) in err
    assert table.read_bytes() == broken and not (out / "mesh").exists()   # no loop ran
