"""Seed 000's model validation (``verification.sweep``, ``tissue verify --sweep``): the
experiments' bookkeeping and the error statistics checked against answers known by
construction (a solver off the reference by known offsets, an exact solver), numpy's statistics
of those offsets, and the case's measured error bar applied by hand."""
import json

import numpy as np
import pytest

from tissue_reference.errors import CaseError
from tissue_reference.model.case import load_case
from tissue_reference.model.results import SolveResult
from tissue_reference.tissue.cli import main
from tissue_reference.tissue.output_schema import validate_file
from tissue_reference.verification.sweep import error_statistics, experiments, sweep

BOX = """name = "box2"
[mesh]
builtin = "box"
size = 5.0
[material]
model = "neo-hookean"
E = 6.0
nu = 0.45
[[boundary]]
region = "xmin"
type = "fixed"
[[actuator]]
name = "A1"
region = "xmax"
direction = [-1.0, 0.0, 0.0]
[[actuator]]
name = "A2"
region = "xmax"
direction = [0.0, -1.0, 0.0]
[[probe]]
name = "T1"
point = [5.0, 5.0, 5.0]
[[probe]]
name = "T2"
point = [7.5, 2.5, 4.0]
[[probe]]
name = "T3"
point = [2.0, 8.0, 6.0]
"""
PUSHES = (1.0, 2.0, 3.0)


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "box2.toml"
    path.write_text(BOX)
    # A1 pushes the face xmax in, A2 shears it; the idle one moves with the tissue
    return load_case(path).with_free_actuators()


def _field(case, pushes):
    """A smooth displacement field (mm) at the case's vertices under ``pushes``: each actuator
    moves the body along its direction in proportion to its push and to x (the fixed face at
    x = 0 stays), with a quadratic bulge: a stand-in for the reference, known in closed form."""
    X = case.mesh.points
    u = np.zeros_like(X)
    for a in case.actuators:
        p = float(pushes.get(a.name, 0.0))
        u += p * (X[:, [0]] / 10.0) * np.asarray(a.direction) \
            + 0.01 * p ** 2 * np.column_stack([X[:, 1], X[:, 2], X[:, 0]]) * X[:, [0]] / 100.0
    return u


def _pushes_of(case):
    return {a.name: float(a.push or 0.0) for a in case.actuators}


def _fake_reference(case, extra=None):
    """The stand-in reference: ``_field`` at the case's pushes, as a SolveResult."""
    u = _field(case, _pushes_of(case))
    return SolveResult(u=u, converged=True, iterations=3, residual=0.0, wall_time_s=0.01,
                       solver="fem", probes=case.probe_values(u), valid=True,
                       extra=dict(extra or {}))


def _offset(pushes):
    """The known error of the offset solver: a vector per experiment, (mm)."""
    (name, p), = pushes.items()
    k = 1.0 if name == "A1" else -2.0
    return np.array([0.1 * k * p, -0.05 * p ** 2, 0.02 * k])


def offset_solver(case, pushes):
    """The reference's field plus ``_offset`` at every vertex."""
    return _field(case, pushes) + _offset(pushes)


def exact_solver(case, pushes):
    return _field(case, pushes)


def test_the_experiments_are_each_actuator_alone_at_each_push(box):
    runs = experiments(box, PUSHES)
    assert runs == [{"A1": 1.0}, {"A1": 2.0}, {"A1": 3.0}, {"A2": 1.0}, {"A2": 2.0}, {"A2": 3.0}]
    assert experiments(box, (5,), ["A2"]) == [{"A2": 5.0}]
    for bad in ((PUSHES, ["A9"]), ((0.0,), None), ((), None), (PUSHES, ["A1", "A1"])):
        with pytest.raises(CaseError):
            experiments(box, *bad)


def test_the_statistics_are_numpys():
    v = np.array([0.3, -1.2, 0.7, 2.5, -0.1, 0.0, 1.1])
    s = error_statistics(v)
    assert s["n"] == 7
    assert s["mean"] == pytest.approx(v.mean(), abs=1e-15)
    assert s["median"] == 0.3 and s["min"] == -1.2 and s["max"] == 2.5
    q25, q75 = np.percentile(v, [25, 75])
    assert s["q25"] == pytest.approx(q25) and s["q75"] == pytest.approx(q75)
    assert s["std"] == pytest.approx(v.std())
    assert error_statistics([])["mean"] is None


def test_a_solver_off_by_known_offsets_scores_exactly_those_offsets(box):
    res = sweep(box, [offset_solver, exact_solver], pushes_mm=PUSHES,
                reference_solve=_fake_reference)
    runs = experiments(box, PUSHES)
    known = np.array([_offset(p) for p in runs])                    # (6, 3): the errors
    assert [r["pushes_mm"] for r in res["experiments"]] == runs
    name = next(n for n in res["summary"] if "offset_solver" in n)
    exact = next(n for n in res["summary"] if "exact_solver" in n)
    for r, off, p in zip(res["experiments"], known, runs):
        ref = _field(box, p)
        for t in res["targets"]:
            # the reference's targets are the field interpolated at them; the solver's the
            # same plus the offset (P1 interpolation reproduces a constant)
            assert np.allclose(r["reference"]["probes_mm"][t], box.probe_values(ref)[t],
                               atol=1e-13)
            assert np.allclose(r["solvers"][name]["error_mm"][t], off, atol=1e-12)
            assert r["solvers"][name]["distance_mm"][t] == pytest.approx(
                np.linalg.norm(off), abs=1e-12)
            assert r["solvers"][exact]["distance_mm"][t] == 0.0
    summ = res["summary"][name]
    for t in res["targets"]:
        for j, ax in enumerate("xyz"):
            s, a = summ["targets"][t][ax]["signed"], summ["targets"][t][ax]["absolute"]
            assert s["mean"] == pytest.approx(known[:, j].mean(), abs=1e-12)
            assert s["median"] == pytest.approx(np.median(known[:, j]), abs=1e-12)
            assert s["min"] == pytest.approx(known[:, j].min(), abs=1e-12)
            assert s["max"] == pytest.approx(known[:, j].max(), abs=1e-12)
            assert a["mean"] == pytest.approx(np.abs(known[:, j]).mean(), abs=1e-12)
            assert a["max"] == pytest.approx(np.abs(known[:, j]).max(), abs=1e-12)
            assert summ["targets"][t][ax]["rms"] == pytest.approx(
                np.sqrt(np.mean(known[:, j] ** 2)), abs=1e-12)
        assert summ["targets"][t]["distance"]["mean"] == pytest.approx(
            np.linalg.norm(known, axis=1).mean(), abs=1e-12)
    # the largest error: y of A1 = 3 or A2 = 3 (0.45 mm), or x of A2 = 3 (0.6 mm)
    assert summ["max_abs_error_mm"] == pytest.approx(0.6, abs=1e-12)
    assert summ["axis"] == "x" and summ["pushes_mm"] == {"A2": 3.0}
    assert res["summary"][exact]["max_abs_error_mm"] == 0.0
    # no measured accuracy in the case: the output says so and invents no error bar
    assert res["reference_error_bar"]["max_mm"] is None
    assert "no [[reference.measured]] rows" in res["reference_error_bar"]["note"]
    assert res["seed_fig7"]["max_abs_error_mm"] == 1.6


def test_the_reference_error_bar_is_the_case_rows_fraction_of_each_target(box):
    row = {"converged": True, "probes": 0.01, "band": {"probes": 0.02}}
    res = sweep(box, [exact_solver], pushes_mm=(2.0,), actuators=["A1"],
                reference_solve=lambda c: _fake_reference(c, {"measured_accuracy": row}))
    ref = box.probe_values(_field(box, {"A1": 2.0}))
    bar = res["experiments"][0]["reference"]["error_bar_mm"]
    for t in res["targets"]:
        assert bar[t] == pytest.approx(0.03 * np.linalg.norm(ref[t]), rel=1e-12)
    assert res["reference_error_bar"]["max_mm"] == bar


def test_an_exact_solver_scores_zero_against_the_reference_and_admm_its_solver_error(box):
    """With the real reference: a plugin that solves the case as the reference does is off by
    nothing; ADMM with its Newton polish (verify's ``admm``), on the same law and mesh, by its
    solver error only."""
    import tissue_reference.fem_reference as fr

    def reference_plugin(case, pushes):
        return fr.solve(case, pushes=pushes).u

    res = sweep(box, ["admm", reference_plugin], pushes_mm=(1.0,), actuators=["A1"])
    assert res["summary"]["admm"]["model"] == "neo-hookean"
    plugin = next(n for n in res["summary"] if n != "admm")
    assert res["summary"][plugin]["max_abs_error_mm"] < 1e-12
    assert 0.0 < res["summary"]["admm"]["max_abs_error_mm"] < 1e-6
    moved = np.linalg.norm(res["experiments"][0]["reference"]["probes_mm"]["T2"])
    assert moved > 0.05


def test_tissue_verify_sweep_writes_its_json_and_plot_and_refuses_a_push(box, tmp_path, capsys):
    path = tmp_path / "box2.toml"
    path.write_text(BOX)
    js, out = tmp_path / "s.json", tmp_path / "plot"
    assert main(["verify", str(path), "--sweep", "1", "--sweep-actuators", "A2", "-q",
                 "--free-actuators", "--model-E-factor", "1.2",
                 "--json", str(js), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "seed 000 Fig. 7" in text and "no [[reference.measured]] rows" in text
    assert "E = 7.2 kPa" in text        # the model's stiffness, 1.2 times the case's
    data = validate_file("verify_sweep", js)
    assert [r["pushes_mm"] for r in data["experiments"]] == [{"A2": 1.0}]
    assert (out / "sweep_errors.png").stat().st_size > 0
    summ = json.loads(js.read_text())["summary"]["admm"]
    assert summ["experiments"] == 1
    # pushes prescribed, no gravity: the energy scales with E at a fixed nu and its minimizer
    # does not move, so a model 1.2 times stiffer predicts the same targets (to ADMM's error)
    assert summ["max_abs_error_mm"] < 1e-6
    assert main(["verify", str(path), "--sweep", "1", "--push", "A1=1", "-q"]) == 2
    assert "not with --sweep" in capsys.readouterr().err
    assert main(["verify", str(path), "--model-size", "4", "-q"]) == 2


def test_a_sweep_solves_the_reference_at_the_degree_it_is_given(tmp_path):
    """--degree with --sweep: the reference (the tracker) is solved at that degree, and every
    experiment records the degree it was solved at (the case's without --degree: P1 here)."""
    path = tmp_path / "box2.toml"
    path.write_text(BOX)
    for degree in (None, 2):
        js = tmp_path / f"s{degree}.json"
        argv = ["verify", str(path), "--sweep", "1", "--sweep-actuators", "A1", "-q",
                "--free-actuators", "--json", str(js)]
        assert main(argv + (["--degree", str(degree)] if degree else [])) == 0
        data = validate_file("verify_sweep", js)
        assert [r["reference"]["degree"] for r in data["experiments"]] == [degree or 1]


def test_a_stiffer_model_is_solved_on_the_scaled_E_and_another_body_is_refused(box):
    """--model-E-factor: the solvers get the case with E scaled; a model whose displacement is
    inversely proportional to E then predicts the reference's targets divided by the factor."""
    import dataclasses

    def compliant(case, pushes):
        return _field(case, pushes) * (6.0 / case.material.E)

    res = sweep(box, [compliant], pushes_mm=(2.0,), actuators=["A1"], model_E_factor=1.25,
                reference_solve=_fake_reference)
    assert res["model_case"]["material"]["E_kPa"] == pytest.approx(7.5)
    (name,) = res["summary"]
    r = res["experiments"][0]
    for t in res["targets"]:
        assert np.allclose(r["solvers"][name]["probes_mm"][t],
                           np.asarray(r["reference"]["probes_mm"][t]) / 1.25, atol=1e-13)
    other = dataclasses.replace(box, probes=box.probes[:1])
    with pytest.raises(CaseError, match="probes"):
        sweep(box, [compliant], model_case=other, reference_solve=_fake_reference)
    with pytest.raises(CaseError, match="E factor"):
        sweep(box, [compliant], model_E_factor=-1.0, reference_solve=_fake_reference)
