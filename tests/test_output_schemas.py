"""Every JSON file the command line writes matches its schema (tissue/schemas/*.schema.json):
each command runs once on a small case, its real output is validated, and an output missing a
key that says what was computed is refused with that key and its place named."""
import copy
import json
import tomllib
from pathlib import Path

import pytest
from test_cli_fuzz import BOX as CLI_BOX  # the small box case of the CLI tests

from tissue_reference.tissue.cli import main
from tissue_reference.tissue.output_schema import (
    OutputSchemaError,
    json_path,
    names,
    schema,
    validate,
    validate_file,
)

ROOT = Path(__file__).resolve().parents[1]
PHANTOM = str(ROOT / "meshes" / "cases" / "phantom.toml")
BOX = CLI_BOX.format(model="neo-hookean")

# run name -> (schema, command line, exit status, the JSON files it writes, relative to the run's
# folder); BOX stands for the box case file, OUT for the run's folder
RUNS = {
    "solve": ("solve", ["solve", "BOX", "--push", "A1=1", "-q", "--json", "OUT/r.json"], 0,
              ["r.json"]),
    "solve-estimate": ("solve", ["solve", "BOX", "--push", "A1=1", "--estimate", "-q",
                                 "--json", "OUT/r.json"], 0, ["r.json"]),
    "solve-admm": ("solve", ["solve", "BOX", "--push", "A1=1", "--solver", "admm", "-q",
                             "--json", "OUT/r.json"], 0, ["r.json"]),
    "solve-mass-tensor": ("solve", ["solve", "BOX", "--push", "A1=1", "--solver",
                                    "mass-tensor", "-q", "--json", "OUT/r.json"], 0, ["r.json"]),
    "verify": ("verify", ["verify", "BOX", "--push", "A1=1", "-q", "--json", "OUT/v.json"], 0,
               ["v.json"]),
    "verify-sweep": ("verify_sweep", ["verify", "BOX", "--sweep", "1", "-q", "--json",
                                      "OUT/s.json"], 0, ["s.json"]),
    "suite": ("suite", ["suite", "--solvers", "fem", "admm", "--problems", "shear-patch", "-q",
                        "--json", "OUT/s.json"], 0, ["s.json"]),
    "converge": ("converge", ["converge", "BOX", "--push", "A1=1", "--levels", "3", "-q",
                              "--json", "OUT/c.json", "--out", "OUT/c"], 0,
                 ["c.json", "c/convergence.json"]),
    "jacobian": ("jacobian", ["jacobian", "BOX", "--state-push", "A1=1", "-q", "--json",
                              "OUT/j.json"], 0, ["j.json"]),
    "jacobian-admm": ("jacobian", ["jacobian", "BOX", "--state-push", "A1=1", "--solver",
                                   "admm", "--fd-h", "0", "-q", "--json", "OUT/j.json"], 0,
                      ["j.json"]),
    "dynamics": ("dynamics", ["dynamics", "BOX", "--push", "A1=1", "--dt", "0.1", "--steps",
                              "3", "-q", "--json", "OUT/d.json"], 0, ["d.json"]),
    "dynamics-admm": ("dynamics", ["dynamics", "BOX", "--push", "A1=1", "--dt", "0.1",
                                   "--steps", "3", "--solver", "admm", "-q", "--json",
                                   "OUT/d.json"], 0, ["d.json"]),
    # tasks of 2 mm keep the box's glued patch (7.1 mm radius) within the pushes where its
    # answers converge; the seed's 5 mm task pushes it past them (exit status 1, the JSON says so)
    "mpc": ("mpc", ["mpc", "BOX", "--target", "T1", "--task", "1", "--steps", "3", "-q",
                    "--task-mm", "2", "--json", "OUT/m.json"], 0, ["m.json"]),
    "mpc-outside-range": ("mpc", ["mpc", "BOX", "--target", "T1", "--task", "1", "--steps", "3",
                                  "-q", "--json", "OUT/m.json"], 1, ["m.json"]),
    # the box's one actuator pushes along -x: task 2 (-y) is out of its reach (exit status 2,
    # the JSON says so)
    "mpc-unreachable": ("mpc", ["mpc", "BOX", "--target", "T1", "--task", "2", "--steps", "3",
                                "-q", "--json", "OUT/m.json"], 2, ["m.json"]),
    "table1": ("table1", ["table1", "BOX", "--steps", "3", "-q", "--task-mm", "2", "--out",
                          "OUT/t"], 0, ["t/table1.json"]),
    "table1-outside-range": ("table1", ["table1", "BOX", "--steps", "3", "-q", "--out", "OUT/t"],
                             1, ["t/table1.json"]),
    "table1-scenarios": ("table1_scenarios", ["table1", "BOX", "--steps", "3", "-q",
                                              "--task-mm", "2", "--scenarios", "gravity",
                                              "--out", "OUT/t"], 0,
                         ["t/table1_scenarios.json"]),
    "manipulability": ("manipulability", ["manipulability", PHANTOM, "--size", "14",
                                          "--compare", "--spacing", "6", "-q", "--out",
                                          "OUT/m"], 0, ["m/manipulability_phantom.json"]),
    "implant": ("implant", ["implant", "--synthetic", "--no-reference", "-q", "--json",
                            "OUT/i.json"], 0, ["i.json"]),
    # the demo at coarse sizes, P1 and small pushes (its default takes minutes)
    "demo": ("demo", ["demo", "--out", "OUT/d", "--size", "14", "--degree", "1", "--pushes", "1",
                      "2", "--verify-size", "14", "--verify-push", "1", "-q"], 0,
             ["d/summary.json"]),
}


class Outputs:
    """Each run of RUNS once, on demand: (schema, [the data of each JSON file it wrote])."""

    def __init__(self, base: Path):
        self.base = base
        self.case = base / "box.toml"
        self.case.write_text(BOX)
        self.done = {}

    def folder(self, run: str) -> Path:
        return self.base / run

    def get(self, run: str):
        if run not in self.done:
            name, argv, status, files = RUNS[run]
            out = self.folder(run)
            out.mkdir()
            argv = [str(self.case) if a == "BOX" else a.replace("OUT", str(out)) for a in argv]
            assert main(argv) == status, argv
            self.done[run] = (name, [json.loads((out / f).read_text()) for f in files])
        name, data = self.done[run]
        return name, copy.deepcopy(data)


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    return Outputs(tmp_path_factory.mktemp("outputs"))


# --------------------------------------------------------------------------- the schemas
def test_every_output_has_a_schema_and_each_is_a_valid_draft_2020_12_schema():
    from jsonschema import Draft202012Validator

    assert set(names()) == {name for name, *_ in RUNS.values()}
    for name in names() + ["common"]:
        s = schema(name)
        Draft202012Validator.check_schema(s)
        assert s["$schema"] == "https://json-schema.org/draft/2020-12/schema"
        assert s["$id"] == f"urn:tissue-reference:output:{name}"


def test_an_unknown_schema_is_refused_with_the_known_ones_named():
    with pytest.raises(ValueError, match="no output schema 'nope'; schemas: converge, "):
        schema("nope")


def test_the_schemas_are_installed_with_the_package():
    with open(ROOT / "pyproject.toml", "rb") as f:
        data = tomllib.load(f)["tool"]["setuptools"]["package-data"]
    assert "schemas/*.json" in data["tissue_reference.tissue"]


def test_docs_describe_every_output_and_point_at_its_schema():
    text = (ROOT / "docs" / "outputs.md").read_text(encoding="utf-8")
    for name in names() + ["common"]:
        assert f"tissue/schemas/{name}.schema.json" in text, name
    assert "docs/outputs.md" in (ROOT / "README.md").read_text(encoding="utf-8")


# --------------------------------------------------------------------------- real outputs
@pytest.mark.parametrize("run", sorted(RUNS))
def test_a_real_output_matches_its_schema(outputs, run):
    name, files = outputs.get(run)
    for data in files:
        validate(name, data)


def test_validate_file_reads_and_checks_a_written_output(outputs):
    outputs.get("solve")
    data = validate_file("solve", outputs.folder("solve") / "r.json")
    assert data["pushes_mm"] == {"A1": 1.0}


def test_outputs_say_what_was_computed(outputs):
    _, [solve] = outputs.get("solve")
    assert solve["pushes_mm"] == {"A1": 1.0} and solve["material"]["E_kPa"] == 6.0
    assert solve["solver_settings"]["newton"]["max_iterations"] >= 1
    assert solve["discretization"]["formulation"] == "displacement"
    _, [mt] = outputs.get("solve-mass-tensor")
    assert mt["solver_settings"]["method"] == "direct" and "discretization" not in mt
    # each reference run of verify records the pushes it was solved at
    _, [ver] = outputs.get("verify")
    assert ver["reference"]["material"]["model"] == "neo-hookean"
    assert {r["pushes_mm"]["A1"] for r in ver["reference"]["runs"].values()} == {1.0}
    _, [dyn] = outputs.get("dynamics")
    assert dyn["pushes_mm"] == dyn["final"]["pushes_mm"] == {"A1": 1.0}
    _, [jac] = outputs.get("jacobian")
    assert jac["case"] == "box" and jac["discretization"]["cells"] == solve["n_cells"]
    _, [c, c_out] = outputs.get("converge")
    assert c == c_out and c["studies"][0]["formulation"] == "displacement"


# --------------------------------------------------------------------------- violations
# (run, keys to the entry removed): one per schema, and the conditional requirements
MISSING = [
    ("solve", ("material",)),
    ("solve", ("discretization",)),             # required of the reference only
    ("solve-admm", ("solver_settings",)),
    ("verify", ("reference", "material")),
    ("verify", ("reference", "runs", "neo-hookean", "pushes_mm")),
    ("suite", ("problems", 0, "material")),
    ("converge", ("pushes_mm",)),
    ("converge", ("studies", 0, "n_dofs")),
    ("jacobian", ("case",)),
    ("jacobian", ("actuator_kind",)),
    ("mpc", ("plant_material",)),
    ("mpc", ("actuator_positions_mm",)),        # required of a completed run
    ("mpc-unreachable", ("closest_reachable_mm",)),
    ("table1", ("meta", "settings")),
    ("table1-scenarios", ("targets",)),
    ("manipulability", ("discretization",)),
    ("dynamics", ("discretization",)),
    ("dynamics", ("final", "pushes_mm")),
    ("implant", ("material",)),
    ("demo", ("reference", "series", 0, "accuracy")),
    ("demo", ("verify", "reference", "material")),   # the verify schema, inside the demo's
]


@pytest.mark.parametrize("run, keys", MISSING, ids=[f"{r}:{'.'.join(map(str, k))}"
                                                     for r, k in MISSING])
def test_a_missing_required_key_is_named_with_its_place(outputs, run, keys):
    name, [data, *_] = outputs.get(run)
    parent = data
    for k in keys[:-1]:
        parent = parent[k]
    del parent[keys[-1]]
    with pytest.raises(OutputSchemaError) as err:
        validate(name, data)
    assert err.value.path == json_path(keys[:-1])
    assert f"'{keys[-1]}' is a required property" in str(err.value)
    assert f"tissue/schemas/{name}.schema.json" in str(err.value)


PLUGIN = """
import numpy as np


def solve(case, pushes, **options):
    return {"u": np.zeros((case.mesh.n_vertices, case.mesh.gdim)), "iterations": 2,
            "history": {"iteration": [1, 2], "max_step_mm": [0.1, 0.01]},
            "extra": {"model": "linear-elastic", "counts": np.arange(2), "tol": np.float64(1e-3)}}
"""


def test_a_verify_output_with_a_plugins_history_and_extra_matches_its_schema(outputs, tmp_path):
    (tmp_path / "my_plugin.py").write_text(PLUGIN)
    name = f"{tmp_path / 'my_plugin.py'}:solve"
    js = tmp_path / "v.json"
    assert main(["verify", str(outputs.case), "--push", "A1=1", "-q", "--solvers", name,
                 "--json", str(js)]) == 0
    data = validate_file("verify", js)
    e = data["solvers"][name]
    assert e["history"]["iteration"] == [1, 2] and e["extra"] == {"counts": [0, 1], "tol": 1e-3}
    assert e["l2_error_mm"] > 0
    e["history"]["max_step_mm"] = ["big"]
    with pytest.raises(OutputSchemaError) as err:
        validate("verify", data)
    assert err.value.path == json_path(["solvers", name, "history", "max_step_mm", 0])


def test_paths_name_plain_keys_with_dots_and_others_quoted():
    assert json_path([]) == "$"
    assert json_path(["reference", "runs", "neo-hookean", 0]) == \
        "$.reference.runs['neo-hookean'][0]"


def test_a_value_of_the_wrong_type_is_named_with_its_path(outputs):
    _, [data] = outputs.get("solve")
    data["probes"]["T1"]["displacement"][1] = "0.5"
    with pytest.raises(OutputSchemaError) as err:
        validate("solve", data)
    assert err.value.path == "$.probes.T1.displacement[1]"
    assert "'0.5' is not of type 'number'" in err.value.reason


def test_the_demo_summary_says_what_was_run_and_its_page_is_well_formed(outputs, tmp_path):
    from browser_checks import render_page, require_browser
    from page_checks import check_page

    _, [summary] = outputs.get("demo")
    assert summary["mesh"]["size_mm"] == 14.0
    assert summary["mesh"]["case"] == summary["reference"]["case"] == "phantom-indenter-quarter"
    series = summary["reference"]["series"]
    assert [r["push_mm"] for r in series] == [1.0, 2.0]
    for r in series:
        # another size and degree than the case's measured ones: no error bar, and it says so
        assert r["converged"] and r["accuracy"] is None
        assert r["accuracy_line"].startswith("not measured"), r["accuracy_line"]
        assert r["tip_forces_mN"]["A1"] > 0.0
    # the tips press harder the deeper they go
    assert series[1]["tip_forces_mN"]["A1"] > series[0]["tip_forces_mN"]["A1"]
    v = summary["verify"]
    assert v["reference"]["case"] == "phantom-indenter-control"
    assert set(v["solvers"]) == {"admm", "admm-plain", "admm-anderson", "mass-tensor"}
    assert v["solvers"]["mass-tensor"]["reference_model"] == "linear-elastic"
    out = outputs.folder("demo") / "d"
    found = check_page(out / "report.html")
    assert "verify/report.html" in found["links"] and "fem/tips_vs_push.png" in found["images"]
    check_page(out / "verify" / "report.html")
    # what make demo tells a newcomer to open, as a browser draws it: every picture loaded
    drawn = render_page(out / "report.html", require_browser(), tmp_path / "demo.png")
    assert len(drawn["image_widths"]) == len(found["images"]) and min(drawn["image_widths"]) > 0


def test_the_demo_default_answers_carry_measured_error_bars_within_two_percent():
    """What the demo shows by default is ground truth: its case file measured the default
    discretization at every default push, all tips pushed, within 2 % of converged answers."""
    from tissue_reference.fem_reference.solver import default_tip_start
    from tissue_reference.model.case import load_case
    from tissue_reference.tissue.demo import CASE, PUSHES_MM

    case = load_case(CASE)
    start = default_tip_start(case)
    for push in PUSHES_MM:
        rows = [r for r in case.reference_measured
                if set(r["pushes"]) == {a.name for a in case.actuators}
                and all(v == push for v in r["pushes"].values())
                and r.get("contact_quadrature", case.reference_contact_quadrature)
                == case.reference_contact_quadrature and r.get("tip_start", start) == start]
        assert len(rows) == 1, (push, rows)
        assert rows[0].get("converged", True) and rows[0]["force"] <= 0.02 \
            and rows[0]["probes"] <= 0.02, rows[0]


@pytest.mark.slow
def test_the_demo_writes_its_reference_solves_as_tissue_solve_does(tmp_path, capsys):
    """The demo's per-push JSON files (out/fem/tips_*mm.json) are solve outputs: they match
    solve.schema.json, settings included."""
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--size", "14", "--degree", "1", "--pushes", "1", "2",
                 "--skip-verify", "-q"]) == 0
    capsys.readouterr()
    files = sorted((out / "fem").glob("tips_*mm.json"))
    assert [f.name for f in files] == ["tips_1mm.json", "tips_2mm.json"]
    for f in files:
        validate_file("solve", f)
        settings = json.loads(f.read_text())["solver_settings"]
        assert "newton" in settings and settings["estimate"] is False
