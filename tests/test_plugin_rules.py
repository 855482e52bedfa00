"""A solver that is not ours is held to the built-ins' rules: a reported non-convergence fails
--tol, every malformed figure or displacement is a named error (exit status 2, one line), its
answer is checked for validity, and two candidates cannot share a name. What it reports is
kept: its history and extra in the JSON, its convergence plot against its iteration numbers."""
import json

import pytest

from tissue_reference.tissue.cli import main

PLUGINS = '''
import numpy as np


def zero(case, pushes, **options):
    return np.zeros((case.mesh.n_vertices, case.mesh.gdim))


def unconverged(case, pushes, **options):
    return {"u": zero(case, pushes), "converged": False}


def says_no(case, pushes, **options):
    return {"u": zero(case, pushes), "converged": "no"}


def many(case, pushes, **options):
    return {"u": zero(case, pushes), "iterations": "many"}


def fast(case, pushes, **options):
    return {"u": zero(case, pushes), "wall_time_s": "fast"}


def words(case, pushes, **options):
    return {"u": zero(case, pushes), "history": {"max_step_mm": ["big", "small"]}}


def complex_u(case, pushes, **options):
    return zero(case, pushes) + 1e-3j


def pair(case, pushes, **options):
    return zero(case, pushes), {"iterations": 3}


def folded(case, pushes, **options):
    return -2.0 * case.mesh.points     # x = -X: every cell mirrored, so inverted


def scaled(case, pushes, scale=1.0, label="none", **options):
    u = zero(case, pushes)
    u[:, 2] = scale
    return {"u": u, "extra": {"label": label}}


def reporting(case, pushes, **options):
    return {"u": zero(case, pushes), "iterations": 3,
            "history": {"iteration": [2, 4, 6], "max_step_mm": [0.5, 0.05, 0.005],
                        "residual": np.array([1.0, 1e-3, 1e-6])},
            "extra": {"model": "linear-elastic", "counts": np.arange(3), "tol": np.float32(0.25),
                      "sparse": np.bool_(True), "label": "fast", "nested": {"k": (1, 2)},
                      "grid": np.eye(2)}}


def untold(case, pushes, **options):
    return {"u": zero(case, pushes), "history": {"max_step_mm": [0.5, 0.05]}}


class Opaque:
    pass


def opaque(case, pushes, **options):
    return {"u": zero(case, pushes), "extra": {"lu": Opaque()}}


def deep_complex(case, pushes, **options):
    return {"u": zero(case, pushes), "extra": {"poles": {"first": [1.0, 2 + 1j]}}}
'''
CASE = "meshes/cases/phantom.toml"


@pytest.fixture(scope="module")
def plugin_file(tmp_path_factory):
    f = tmp_path_factory.mktemp("plugins") / "candidates.py"
    f.write_text(PLUGINS)
    return f


def _verify(plugin_file, *names, extra=()):
    return main(["verify", CASE, "--size", "14", "--push", "A1=1", "-q", "--solvers",
                 *[f"{plugin_file}:{n}" for n in names], *extra])


def test_a_reported_non_convergence_fails_a_tolerance(plugin_file, capsys):
    assert _verify(plugin_file, "unconverged") == 0
    capsys.readouterr()
    assert _verify(plugin_file, "unconverged", extra=["--tol", "100"]) == 1
    assert "reported converged = false" in capsys.readouterr().err
    assert _verify(plugin_file, "zero", extra=["--tol", "100"]) == 0


@pytest.mark.parametrize("name,words", [("says_no", "converged = 'no'"),
                                        ("many", "iterations = 'many'"),
                                        ("fast", "wall_time_s = 'fast'"),
                                        ("words", "history['max_step_mm']"),
                                        ("complex_u", "complex displacement"),
                                        ("pair", "returned a tuple (u, {...})"),
                                        ("opaque", "extra['lu'] = <"),
                                        ("deep_complex", "extra['poles']['first'][1] = (2+1j)")])
def test_a_malformed_answer_is_a_named_error(plugin_file, capsys, name, words):
    assert _verify(plugin_file, name) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and name in err[0] and "Traceback" not in err[0]


def test_an_answer_that_folds_every_cell_is_not_valid(plugin_file, tmp_path, capsys):
    js = tmp_path / "v.json"
    assert _verify(plugin_file, "folded", extra=["--json", str(js)]) == 1
    e = json.loads(js.read_text())["solvers"][f"{plugin_file}:folded"]
    assert e["valid"] is False and e["inverted_cells"] > 0
    assert "the answer is not valid" in capsys.readouterr().err


def test_two_candidates_cannot_share_a_name(plugin_file, capsys):
    assert _verify(plugin_file, "zero", "zero") == 2
    assert "given twice" in capsys.readouterr().err


def test_a_solvers_options_come_from_the_command_line(plugin_file, tmp_path, capsys):
    """--option SOLVER KEY=VALUE reaches that solver's solve as a keyword (a JSON value, else
    text); a solver not scored or a setting without '=' is a named error (exit status 2)."""
    name = f"{plugin_file}:scaled"
    out = tmp_path / "v.json"
    _verify(plugin_file, "scaled", extra=["--option", name, "scale=0.25", "--option", name,
                                          "label=big", "--json", str(out)])
    entry = json.loads(out.read_text())["solvers"]
    entry = next(e for n, e in entry.items() if n.endswith("scaled"))
    assert entry["options"] == {"scale": 0.25, "label": "big"}
    assert _verify(plugin_file, "scaled", extra=["--option", "admm", "anderson=5"]) == 2
    assert "'admm' is not among the solvers scored" in capsys.readouterr().err
    assert _verify(plugin_file, "scaled", extra=["--option", name, "scale"]) == 2
    assert "expected KEY=VALUE" in capsys.readouterr().err


def test_a_plugins_history_and_extra_are_kept_in_the_json(plugin_file, tmp_path):
    """All of its extra but the model (stated as the model it solves) and its whole history,
    NumPy arrays and scalars as lists and numbers."""
    js = tmp_path / "v.json"
    assert _verify(plugin_file, "reporting", extra=["--json", str(js)]) == 0
    e = json.loads(js.read_text())["solvers"][f"{plugin_file}:reporting"]
    assert e["history"] == {"iteration": [2, 4, 6], "max_step_mm": [0.5, 0.05, 0.005],
                            "residual": [1.0, 1e-3, 1e-6]}
    assert e["extra"] == {"counts": [0, 1, 2], "tol": 0.25, "sparse": True, "label": "fast",
                          "nested": {"k": [1, 2]}, "grid": [[1.0, 0.0], [0.0, 1.0]]}
    assert e["model"] == "linear-elastic" and e["iterations"] == 3


def test_a_plugins_plot_is_drawn_against_its_iteration_numbers(plugin_file, tmp_path,
                                                               monkeypatch):
    """With history["iteration"] the x axis is the iteration numbers and says so; without it,
    the entry's place in the history, and the axis says that instead."""
    import matplotlib.axes

    drawn = []
    real = matplotlib.axes.Axes.set_xlabel

    def spy(self, label, *args, **kwargs):
        drawn.append((label, [line.get_xdata().tolist() for line in self.get_lines()]))
        return real(self, label, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "set_xlabel", spy)
    assert _verify(plugin_file, "reporting", extra=["--out", str(tmp_path / "a")]) == 0
    assert drawn == [("iteration number", [[2, 4, 6]])]
    drawn.clear()
    assert _verify(plugin_file, "untold", extra=["--out", str(tmp_path / "b")]) == 0
    [(label, xs)] = drawn
    assert xs == [[1, 2]] and label.startswith("entry of") and "no iteration numbers" in label
    for out in (tmp_path / "a", tmp_path / "b"):
        [png] = [p for p in out.iterdir() if p.suffix == ".png"]
        assert f"<img src='{png.name}'" in (out / "report.html").read_text()
