"""``tissue verify``: each fast solver against the degree-1 reference on a small phantom."""
import json
import sys
from functools import partial

import numpy as np
import pytest

from tissue_reference.errors import CaseError
from tissue_reference.model.case import load_case
from tissue_reference.tissue.verify_report import write_report
from tissue_reference.verification.verify import verify

CASE = "meshes/cases/phantom.toml"
PUSHES = {"A1": 2.0, "A3": 2.0}


@pytest.fixture(scope="module")
def small_case():
    return load_case(CASE, size=14.0)


@pytest.fixture(scope="module")
def run(small_case, tmp_path_factory):
    out = tmp_path_factory.mktemp("verify")
    res = verify(small_case, PUSHES, solvers=("admm", "mass-tensor"),
                 report=partial(write_report, out / "report"), json_file=out / "verify.json",
                 options={"mass-tensor": {"stop_mm": 1e-9}})
    return res, out


def test_json_has_the_error_speed_and_iteration_keys_for_every_solver(run, small_case):
    _, out = run
    on_disk = json.loads((out / "verify.json").read_text())
    assert set(on_disk) >= {"reference", "solvers"}
    for e in on_disk["solvers"].values():
        assert {"probe_error_mm", "max_vertex_error_mm", "rms_vertex_error_mm", "iterations",
                "wall_time_s", "speedup_vs_reference"} <= set(e)
        assert set(e["probe_error_mm"]) == {p.name for p in small_case.probes}
        assert 0 <= e["rms_vertex_error_mm"] <= e["max_vertex_error_mm"]
        assert max(e["probe_error_mm"].values()) <= e["max_vertex_error_mm"] + 1e-12
        # the volume norms of the P1 interpolant of the difference: |e| inside a cell is at
        # most its largest value at the cell's vertices, so the volume RMS is too
        assert 0 <= e["l2_error_mm"] <= e["max_vertex_error_mm"] + 1e-12
        assert np.isfinite(e["h1_seminorm_error"]) and e["h1_seminorm_error"] >= 0
        assert np.isfinite(e["energy_norm_error_sqrt_uJ"]) and e["energy_norm_error_sqrt_uJ"] >= 0
    assert "mass-tensor" in on_disk["solvers"]
    assert on_disk["solvers"]["mass-tensor"]["l2_error_mm"] < 1e-5


def test_json_has_admm_and_reference_iteration_counts(run):
    _, out = run
    on_disk = json.loads((out / "verify.json").read_text())
    for r in on_disk["reference"]["runs"].values():
        assert r["newton_iterations"] >= 1 and r["first_call_wall_time_s"] > 0
    e = on_disk["solvers"]["admm"]
    assert e["admm_iterations"] >= 1 and e["newton_iterations"] >= 0
    assert e["iterations"] == e["admm_iterations"] + e["newton_iterations"]
    assert e["reference_newton_iterations"] == on_disk["reference"]["runs"]["neo-hookean"][
        "newton_iterations"]
    html = (out / "report" / "report.html").read_text()
    assert "ADMM its" in html and "Newton its" in html


def test_solver_registry_resolves_names_and_rejects_unknown_ones():
    from tissue_reference import solvers
    from tissue_reference.solvers import admm, mass_tensor

    assert solvers.get_solver("admm") is admm.solve
    assert solvers.get_solver("mass-tensor") is mass_tensor.solve
    with pytest.raises(CaseError, match="newton"):
        solvers.get_solver("newton")


def test_mass_tensor_compared_with_the_linear_reference_of_the_same_E_nu(run, small_case):
    res, _ = run
    e = res["solvers"]["mass-tensor"]
    assert e["reference_model"] == "linear-elastic"
    lin = res["reference"]["runs"]["linear-elastic"]
    assert lin["E_kPa"] == small_case.material.E and lin["nu"] == small_case.material.nu
    # converged to 1e-9 mm steps, MT equals the linear P1 reference on the same mesh
    assert e["max_vertex_error_mm"] < 1e-5


def test_admm_compared_with_the_case_material_reference(run, small_case):
    res, _ = run
    if "admm" not in res["solvers"]:
        pytest.skip(res["skipped"].get("admm", "admm not run"))
    e = res["solvers"]["admm"]
    assert e["reference_model"] == small_case.material.model == "neo-hookean"
    assert e["max_vertex_error_mm"] < 0.1


def test_report_has_tables_and_one_png_plot_per_solver(run):
    res, out = run
    report = out / "report" / "report.html"
    assert res["report"] == str(report)
    text = report.read_text()
    assert text.count("<table>") == 3
    for name in res["solvers"]:
        png = out / "report" / f"convergence_{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"convergence_{name}.png" in text
    assert not [p for p in (out / "report").iterdir() if p.name.startswith(".")]  # no temp files


def test_every_solver_gets_a_plot_file_name_that_is_safe_and_its_own():
    """No folders, colons or characters a URL escapes; the built-ins keep their names; two
    plugins of one file name in different folders get different files."""
    import re

    from tissue_reference.tissue.verify_report import plot_file

    names = ["admm", "mass-tensor", "admm-plain", "a/b/plugin.py:solve", "c/b/plugin.py:solve",
             "/abs/path/plugin.py:solve", "plugin.py:solve", "test_mod:<lambda>",
             "test_mod:f.<locals>.g", "my dir/my solver.py:run", "C:\\x\\p.py:f",
             "ünï:cödé", "../../up.py:x", "...", ":", "x" * 300]
    files = [plot_file(n) for n in names]
    for n, f in zip(names, files):
        assert re.fullmatch(r"convergence_[A-Za-z0-9][A-Za-z0-9._-]*\.png", f), (n, f)
        assert len(f) < 100, f
    assert len(set(files)) == len(names)
    assert files[:3] == ["convergence_admm.png", "convergence_mass-tensor.png",
                         "convergence_admm-plain.png"]


def test_loose_stopping_rule_gives_a_positive_error_below_the_pushes(small_case):
    res = verify(small_case, PUSHES, solvers=("mass-tensor-pcg", "mass-tensor"),
                 options={"mass-tensor-pcg": {"stop_mm": 0.05}})
    e = res["solvers"]["mass-tensor-pcg"]
    assert 1e-4 < e["max_vertex_error_mm"] < 2.0
    assert 0 < e["l2_error_mm"] <= e["max_vertex_error_mm"]
    assert e["h1_seminorm_error"] > 0 and e["energy_norm_error_sqrt_uJ"] > 0
    # the direct solve has no stopping error: the linear reference's answer to round-off
    assert res["solvers"]["mass-tensor"]["max_vertex_error_mm"] < 1e-9
    assert e["speedup_vs_reference"] > 0


def test_the_amg_mass_tensor_is_within_its_stop_of_the_linear_reference(small_case):
    """mass-tensor-amg stops within an estimated 0.01 mm: the linear reference (dolfinx, the
    same P1 discretization) agrees to that at every vertex."""
    res = verify(small_case, PUSHES, solvers=("mass-tensor-amg",))
    e = res["solvers"]["mass-tensor-amg"]
    assert 0 < e["max_vertex_error_mm"] < 0.01


def test_missing_fast_solver_module_is_skipped_with_a_message(small_case, monkeypatch, capsys):
    # importing it raises ImportError
    monkeypatch.setitem(sys.modules, "tissue_reference.solvers.admm", None)
    res = verify(small_case, PUSHES, solvers=("admm", "mass-tensor"),
                 options={"mass-tensor": {"stop_mm": 0.1}})
    assert "admm" in res["skipped"] and "admm" not in res["solvers"]
    assert "mass-tensor" in res["solvers"]
    assert "skipped" in capsys.readouterr().out


def test_unknown_solver_or_actuator_rejected_before_any_solve(small_case):
    with pytest.raises(CaseError, match="newton"):
        verify(small_case, PUSHES, solvers=("newton",))
    with pytest.raises(CaseError, match="A9"):
        verify(small_case, {"A9": 1.0}, solvers=("mass-tensor",))


def test_cli_verify_writes_json_and_report(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    js = tmp_path / "v.json"
    rc = main(["verify", CASE, "--size", "14", "--push", "A2=1.5", "--solvers", "mass-tensor",
               "--stop-mm", "0.001", "--json", str(js), "--out", str(tmp_path / "rep")])
    assert rc == 0
    data = json.loads(js.read_text())
    assert data["reference"]["pushes_mm"] == {"A2": 1.5}
    assert data["solvers"]["mass-tensor"]["options"]["stop_mm"] == 0.001
    assert (tmp_path / "rep" / "report.html").is_file()
    assert "mass-tensor" in capsys.readouterr().out


def test_cli_bad_push_reports_error_exit_code(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    rc = main(["verify", CASE, "--size", "14", "--push", "A1", "--solvers", "mass-tensor"])
    assert rc == 2
    assert "NAME=MM" in capsys.readouterr().err


def test_plot_trace_error_is_the_distance_to_the_reference(small_case, tmp_path):
    # the traced error of the last iteration equals the reported max vertex error (same run
    # settings, deterministic solver)
    seen = {}

    def spy(case, out, traces):
        seen.update(traces)
        return write_report(tmp_path, case, out, traces)

    res = verify(small_case, PUSHES, solvers=("mass-tensor-pcg",), report=spy,
                 options={"mass-tensor-pcg": {"stop_mm": 0.05}})
    tr = seen["mass-tensor-pcg"]
    got = res["solvers"]["mass-tensor-pcg"]
    assert len(tr["iteration"]) == got["iterations"]
    assert np.isclose(tr["max_error_mm"][-1], got["max_vertex_error_mm"], rtol=1e-9)
    assert tr["max_step_mm"][-1] < 0.05 <= min(tr["max_step_mm"][:-1])


def test_discretization_error_is_reported_beside_the_solver_error(small_case):
    """With estimate=True each solver's entry carries the reference's own estimated
    discretization error per probe, a different quantity from its error to the reference."""
    out = verify(small_case, {"A1": 5.0}, solvers=("mass-tensor",), estimate=True)
    e = out["solvers"]["mass-tensor"]
    assert set(e["discretization_error_estimate_mm"]) == set(e["probe_error_mm"])
    assert all(v > 0 for v in e["discretization_error_estimate_mm"].values())
    run = out["reference"]["runs"]["linear-elastic"]
    assert run["estimate_discretization"]["degree"] == 2
