"""A case file's measured accuracy (``[reference.measured]``): a solve reports the row of exactly
its discretization (unknowns, degree, contact rule, tip start) and load, and no row for anything
else; a bad row is refused naming the file and the key; the shipped rows describe their cases'
defaults.
Units: mm."""
import dataclasses
import itertools
import json
import re
from pathlib import Path

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.fem_reference.measured import measured_accuracy, with_measured_accuracy
from tissue_reference.model.case import load_case

CASES = Path(__file__).resolve().parents[1] / "meshes" / "cases"
QUARTER = CASES / "phantom-quarter.toml"    # glued patches, P1 by default


def _row(dofs, pushes, **kw):
    row = {"pushes": pushes, "dofs": dofs, **kw}
    if kw.get("converged") is not False:
        row.setdefault("probes", 0.05)
        row.setdefault("against", "a finer mesh")
    return row


@pytest.fixture(scope="module")
def coarse():
    case = load_case(QUARTER, size=14)
    return case, fr.solve(case, pushes={"A1": 1.0})


def test_a_row_describes_exactly_its_discretization_and_load(coarse):
    case, res = coarse
    n = res.discretization["dofs"]
    assert n == 3 * case.mesh.n_vertices     # P1 displacement: three unknowns per vertex
    rows = (_row(n, {"A1": 2.0}, probes=0.2), _row(n + 3, {"A1": 1.0}, probes=0.3),
            _row(n, {"A1": 1.0}, degree=2, probes=0.4), _row(n, {"A1": 1.0, "A2": 1.0}),
            _row(n, {"A1": 1.0}, contact_quadrature=2, probes=0.6),
            _row(n, {"A1": 1.0, "A2": 0.0}, probes=0.07))
    with_rows = dataclasses.replace(case, reference_measured=rows)
    got = measured_accuracy(with_rows, res, {"A1": 1.0})
    assert got == {"converged": True, **rows[-1]}     # the actuators not named are at 0
    assert measured_accuracy(with_rows, res, {"A1": 1.0 + 1e-6}) is None
    assert measured_accuracy(case, res, {"A1": 1.0}) is None      # a case without rows
    assert "measured_accuracy" not in with_measured_accuracy(case, res, {"A1": 1.0}).extra
    # the same load at degree 2 is another discretization: no row
    p2 = fr.solve(case, pushes={"A1": 1.0}, degree=2)
    assert measured_accuracy(with_rows, p2, {"A1": 1.0}) is None
    # fr.solve reports the row itself, and only for its own load; otherwise it names the
    # loads measured on this discretization (the nodal rule's: not the Gauss rule's row)
    assert fr.solve(with_rows, pushes={"A1": 1.0}).extra["measured_accuracy"] == got
    other = fr.solve(with_rows, pushes={"A1": 0.5}).extra
    assert "measured_accuracy" not in other
    assert other["measured_note"] == (
        "not measured for this load: on this discretization (contact rule nodal) the case "
        "measured A1 = 2; A1 = 1, A2 = 1; A1 = 1, A2 = 0 mm")
    assert "this answer has 3 unknowns" not in other["measured_note"]
    assert "measured_note" not in fr.solve(case, pushes={"A1": 0.5}).extra   # no rows
    assert p2.extra.get("measured_note") is None   # fr.solve on the case without rows
    note = with_measured_accuracy(with_rows, p2, {"A1": 1.0}).extra["measured_note"]
    assert note == f"not measured: the case's measurements are of {n}, {n + 3} unknowns, this " \
                   f"answer has {p2.discretization['dofs']} (contact rule nodal)"


def test_a_row_is_of_one_tip_start(coarse):
    """Where the indenters started is part of the discretization: a row measured with tips
    started on the skin's nodes (the case's start) does not describe an answer whose tips
    started on its curved facets, and a row that names that start does."""
    case, res = coarse
    case = dataclasses.replace(case, reference_tip_start="nodes")
    n = res.discretization["dofs"]
    started = {}
    for how in ("nodes", "surface"):
        started[how] = dataclasses.replace(
            res, indenters={"A1": {"quadrature": "nodal", "started_on": how}})
    rows = (_row(n, {"A1": 1.0}, probes=0.1), _row(n, {"A1": 1.0}, tip_start="surface",
                                                   probes=0.2))
    with_rows = dataclasses.replace(case, reference_measured=rows)
    assert measured_accuracy(with_rows, started["nodes"], {"A1": 1.0})["probes"] == 0.1
    assert measured_accuracy(with_rows, started["surface"], {"A1": 1.0})["probes"] == 0.2
    only_nodes = dataclasses.replace(case, reference_measured=rows[:1])
    assert measured_accuracy(only_nodes, started["surface"], {"A1": 1.0}) is None
    # a case whose own start is "surface" makes that the rows' default
    surface_case = dataclasses.replace(only_nodes, reference_tip_start="surface")
    assert measured_accuracy(surface_case, started["surface"], {"A1": 1.0})["probes"] == 0.1


def _with_rows(tmp_path, rows: str) -> Path:
    path = tmp_path / "quarter.toml"
    path.write_text(QUARTER.read_text() + "\n" + rows)
    return path


def test_a_solve_that_overrides_the_rule_or_start_gets_the_row_of_what_it_solved(tmp_path,
                                                                                 coarse):
    """A row that names no contact rule or tip start was measured with the case file's; the
    command line's --contact-quadrature and --tip-start replace the case's, not the rows'."""
    _, res = coarse
    n = res.discretization["dofs"]
    measured = (("", 0.01, "the nodal rule, on the nodes"),
                ("contact_quadrature = 2\n", 0.02, "a Gauss rule, on the surface"),
                ('contact_quadrature = 2\ntip_start = "nodes"\n', 0.03,
                 "a Gauss rule, on the nodes"))
    case = load_case(_with_rows(tmp_path, "".join(
        f'\n[[reference.measured]]\npushes = {{A1 = 1.0}}\ndofs = {n}\n{named}probes = {probes}\n'
        f'against = "{what}"\n' for named, probes, what in measured)), size=14)
    for rule, start, probes in (("nodal", "nodes", 0.01), (2, "surface", 0.02),
                                (2, "nodes", 0.03)):
        answer = dataclasses.replace(
            res, indenters={"A1": {"quadrature": rule, "started_on": start}})
        for override in ({}, {"reference_contact_quadrature": rule},
                         {"reference_contact_quadrature": rule, "reference_tip_start": start}):
            solved = dataclasses.replace(case, **override)     # as the command line does
            assert measured_accuracy(solved, answer, {"A1": 1.0})["probes"] == probes


UNKNOWN_ACTUATOR = """
[[reference.measured]]
pushes = {A9 = 5.0}
dofs = 100
probes = 0.01
against = "x"
"""


def test_bad_rows_are_refused_naming_the_file_and_the_key(tmp_path):
    path = _with_rows(tmp_path, UNKNOWN_ACTUATOR + """
[[reference.measured]]
pushes = {A1 = -1.0}
dofs = 100
converged = false
probes = 0.01
""")
    with pytest.raises(CaseError) as err:   # the schema's faults first, one line each
        load_case(path)
    msg = str(err.value)
    assert f"{path}: [reference].measured[2].pushes.A1: expected a finite number >= 0, found -1" \
        in msg
    assert "[reference].measured[2].probes: expected no probes with converged = false" in msg
    assert "[reference].measured[2].why: expected a string, found nothing" in msg
    with pytest.raises(CaseError, match=r"measured\[1\]\.pushes\.A9: expected one of the "
                                        r"case's actuators \(A1, A2\), found 'A9'"):
        load_case(_with_rows(tmp_path, UNKNOWN_ACTUATOR))


def test_the_command_line_prints_the_row_and_warns_where_nothing_converged(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    n = 3 * load_case(QUARTER, size=14).mesh.n_vertices
    path = _with_rows(tmp_path, f"""
[[reference.measured]]
pushes = {{A1 = 1.0}}
dofs = {n}
probes = 0.05
against = "a finer mesh of the test"

[[reference.measured]]
pushes = {{A1 = 1.5}}
dofs = {n}
converged = false
why = "the test says so"
""")
    js = tmp_path / "s.json"
    assert main(["solve", str(path), "--size", "14", "--push", "A1=1", "-q",
                 "--json", str(js), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr()
    assert "Accuracy: measured for this discretization and load: probes within 5.00%" in \
        (tmp_path / "o" / "report.html").read_text()
    assert "accuracy: measured for this discretization and load: probes within 5.00% of the " \
           "converged value: a finer mesh of the test" in out.out
    assert json.loads(js.read_text())["measured_accuracy"]["against"] == \
        "a finer mesh of the test"
    assert main(["solve", str(path), "--size", "14", "--push", "A1=1.5", "-q",
                 "--json", str(js)]) == 0
    out = capsys.readouterr()
    assert "no converged value is known at this load (the test says so): this answer has no " \
           "error bar" in json.loads(js.read_text())["warnings"]   # one of the answer's warnings
    assert "accuracy: none: no converged value is known at this load (the test says so)" in \
        out.out
    assert "warning: no converged value is known at this load (the test says so): this answer " \
           "has no error bar" in out.err
    assert main(["solve", str(path), "--size", "14", "--push", "A1=1", "--degree", "2",
                 "-q", "--no-estimate"]) == 0
    assert "accuracy: not measured: the case's measurements are of " in capsys.readouterr().out


@pytest.mark.parametrize("name", ["phantom-indenter", "phantom-indenter-quarter",
                                  "phantom-indenter-half", "phantom-indenter-wide",
                                  "phantom-indenter-control"])
def test_the_shipped_rows_describe_their_cases_defaults(name):
    """Each row's unknowns are the case's own at its degree (P2: three per vertex and per edge),
    so a change of the default mesh cannot leave its measurements behind unnoticed."""
    case = load_case(CASES / f"{name}.toml")
    assert case.reference_measured and case.reference_degree == 2
    cells = case.mesh.cells
    edges = np.unique(np.sort(np.vstack([cells[:, e] for e in itertools.combinations(range(4),
                                                                                    2)]), axis=1),
                      axis=0)
    dofs = 3 * (case.mesh.n_vertices + len(edges))
    for row in case.reference_measured:
        assert row["dofs"] == dofs and row.get("degree", 2) == 2
        assert row.get("converged", True) == ("why" not in row)


DATA = Path(__file__).resolve().parent / "data" / "phantom_indenter_reference.json"


def _from_study(key: str, level: int, push: float, ref_key: str) -> tuple[float, float]:
    """(force, worst probe) differences of ``level`` of a study in the data file from the
    finest level of the study ``ref_key``, at ``push`` (mm)."""
    loads = json.loads(DATA.read_text())["loads"]
    row = next(e for e in loads[key]["pushes"] if e["push_mm"] == push)
    ref = next(e for e in loads[ref_key]["pushes"] if e["push_mm"] == push)
    i = row["levels"].index(level)
    force = abs(row["force_mN"][i] / ref["force_mN"][-1] - 1.0)
    probes = max(np.linalg.norm(np.subtract(row["probes_mm"][n][i], v[-1])) / np.linalg.norm(v[-1])
                 for n, v in ref["probes_mm"].items())
    return force, probes


QUARTER_ANSWERS = DATA.parent / "phantom_indenter_quarter_default.json"
"""The quarter indenter case's default answers along its load path, all four tips pushed
equally (``bench/bench_default_accuracy.py --case quarter --loads four --answers``)."""


def test_the_quarter_case_s_rows_are_its_answers_distance_from_the_finest_level():
    """The quarter indenter case's rows hold the distance of its shipped default answers (solved
    on the case's own mesh, with its rule and tip start) from the finest level of the Gauss-rule
    study started on the curved skin, computed here from the two data files, not numbers typed
    in by hand; every push the answers reached has its row, and the answers are the case's own
    discretization."""
    case = load_case(CASES / "phantom-indenter-quarter.toml")
    answers = json.loads(QUARTER_ANSWERS.read_text())
    assert answers["asked"]["case"] == "quarter" and answers["asked"]["mesh"] is None
    loads = json.loads(DATA.read_text())["loads"]
    study = loads["four_gauss_surface"]
    rows = {row["pushes"]["A1"]: row for row in case.reference_measured}
    assert all(len(row["pushes"]) == len(case.actuators) for row in rows.values())
    checked = set()
    for ans in answers["four"]["rows"]:
        assert ans["converged"] and ans["valid"] and ans["dofs"] == rows[ans["push"]]["dofs"]
        assert (ans["rule"], ans["start"]) == (2, "surface")
        row = rows[ans["push"]]
        ref = next(e for e in study["pushes"] if e["push_mm"] == ans["push"])
        if not row.get("converged", True):
            # the study's force there is known to no better than 10 % (its GCI band)
            assert ref["quantities"]["force A1"]["gci_rel"] > 0.1
            checked.add(ans["push"])
            continue
        assert ref["dofs"][-1] > 3 * ans["dofs"]          # a far finer discretization
        force = abs(ans["force"] / ref["force_mN"][-1] - 1.0)
        probes = max(np.linalg.norm(np.subtract(ans["probes"][n], v[-1])) / np.linalg.norm(v[-1])
                     for n, v in ref["probes_mm"].items())
        assert row["force"] == pytest.approx(force, abs=6e-5)
        assert row["probes"] == pytest.approx(probes, abs=6e-5)
        assert row["force"] < 0.02 and row["probes"] < 0.02
        checked.add(ans["push"])
    assert checked == set(rows) == {5.0, 10.0, 12.5, 15.0}


def test_the_half_case_s_gauss_rows_are_the_study_data_s():
    """With the Gauss rule the half case's default is level 0 of the half's Gauss-rule studies
    (the same unknowns): where a finer level converged at the row's push, its row holds level
    0's differences from the finest in the data file; where level 0 is the finest, that level's
    GCI bands (the force's; each target's components' bands combined as its displacement's
    norm), not a difference of the level from itself."""
    case = load_case(CASES / "phantom-indenter-half.toml")
    loads = json.loads(DATA.read_text())["loads"]
    checked = set()
    for row in case.reference_measured:
        if row["contact_quadrature"] != 2 or not row.get("converged", True):
            continue
        key = "one_gauss" + ("_surface" if row["tip_start"] == "surface" else "")
        push = row["pushes"]["A1"]
        entry = next(e for e in loads[key]["pushes"] if e["push_mm"] == push)
        assert entry["dofs"][entry["levels"].index(0)] == row["dofs"]
        assert f"{key} level {entry['levels'][-1]} (" in row["against"]
        if entry["levels"][-1] > 0:
            force, probes = _from_study(key, 0, push, key)
        else:
            gci = {q: a["gci_rel"] for q, a in entry["quantities"].items()}
            force, probes = gci["force A1"], 0.0
            for name, v in entry["probes_mm"].items():
                u = np.asarray(v[-1])
                parts = [gci.get(f"{name} u{c}") or 0.0 for c in "xyz"]   # none: zero by symmetry
                probes = max(probes,
                             np.linalg.norm(np.multiply(parts, np.abs(u))) / np.linalg.norm(u))
        assert row["force"] == pytest.approx(force, abs=6e-5)
        assert row["probes"] == pytest.approx(probes, abs=6e-5)
        checked.add((row["tip_start"], push))
    assert checked == {(start, push) for start in ("nodes", "surface")
                       for push in (5.0, 10.0, 12.5)}


def _gci_bands(key: str, push: float) -> tuple[float, float]:
    """(force, worst probe) GCI bands of the finest level of a study in the data file at
    ``push``: the force's band, and per probe its components' bands weighted by their sizes,
    as its displacement's norm."""
    entry = next(e for e in json.loads(DATA.read_text())["loads"][key]["pushes"]
                 if e["push_mm"] == push)
    gci = {q: a["gci_rel"] for q, a in entry["quantities"].items()}
    probes = 0.0
    for name, v in entry["probes_mm"].items():
        u = np.asarray(v[-1])
        parts = [gci.get(f"{name} u{c}") or 0.0 for c in "xyz"]   # none: zero by symmetry
        probes = max(probes, np.linalg.norm(np.multiply(parts, np.abs(u))) / np.linalg.norm(u))
    return gci["force A1"], probes


@pytest.mark.parametrize("name", ["phantom-indenter", "phantom-indenter-quarter",
                                  "phantom-indenter-half", "phantom-indenter-wide",
                                  "phantom-indenter-control"])
def test_every_row_against_a_study_carries_that_study_s_band_and_prints_the_sum(name):
    """A row measured against a study of the data file holds that study's own GCI bands at its
    push (computed here from the data), and the answer's error bar, printed and returned, is
    the row's difference plus the band: what the answer is worth, not its distance from a
    level that is itself uncertain."""
    from tissue_reference.fem_reference.measured import describe, error_bar

    case = load_case(CASES / f"{name}.toml")
    checked = 0
    for row in case.reference_measured:
        study = re.search(r"phantom_indenter_reference\.json (\w+) (?:level \d+|finest level)",
                          row.get("against", ""))
        if study is None or row.get("converged") is False:
            assert "band" not in row
            continue
        force, probes = _gci_bands(study[1], row["pushes"]["A1"])
        assert row["band"]["force"] == pytest.approx(force, abs=6e-5)
        assert row["band"]["probes"] == pytest.approx(probes, abs=6e-5)
        bar = error_bar(row)
        assert bar == pytest.approx({"force": row["force"] + force,
                                     "probes": row["probes"] + probes}, abs=1e-4)
        line = describe(row)
        assert f"indenter force within {bar['force']:.2%}, probes within {bar['probes']:.2%} " \
               f"of the converged value ({row['force']:.2%} / {row['probes']:.2%} from the " \
               f"study's finest level" in line
        checked += 1
    assert checked >= 3


def test_the_demo_states_the_error_bar_with_the_band():
    """The demo's accuracy of an answer that a banded row describes: the row's parts and their
    sum, the same line as tissue solve prints."""
    from types import SimpleNamespace

    from tissue_reference.tissue.demo import _accuracy

    case = load_case(CASES / "phantom-indenter-quarter.toml")
    row = {"converged": True, **case.reference_measured[1]}            # all four at 10 mm
    res = SimpleNamespace(extra={"measured_accuracy": row},
                          entries=lambda: {"measured_accuracy": row})
    accuracy, line = _accuracy(res)
    assert accuracy["band"] == row["band"]
    assert accuracy["error_bar"]["probes"] == pytest.approx(row["probes"] + row["band"]["probes"])
    assert accuracy["error_bar"]["force"] == pytest.approx(row["force"] + row["band"]["force"])
    assert f"probes within {row['probes'] + row['band']['probes']:.2%} of the converged" in line
