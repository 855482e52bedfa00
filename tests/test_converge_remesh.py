"""tissue converge --levels-by remesh: level k is the case's builtin built again with every cell
size of its [mesh] table divided by sqrt 2^k, the levels of the indenter phantom's refinement
studies (bench/bench_indenter_convergence.py), assessed with refinement ratio sqrt 2."""
from __future__ import annotations

import json
import math

import pytest

from tissue_reference.fem_reference import convergence, richardson
from tissue_reference.fem_reference.convergence import REMESH_RATIO, remesh_lengths
from tissue_reference.tissue.cli import main

SQRT2 = math.sqrt(2.0)
BOX = """\
name = "box"
[mesh]
builtin = "box"
size = 5.0
[material]
model = "neo-hookean"
E = 6.0
nu = 0.3
[[boundary]]
region = "xmin"
type = "fixed"
[[boundary]]
region = "xmax"
type = "displacement"
value = [0.5, 0.0, 0.0]
[[probe]]
name = "M"
point = [5.0, 5.0, 5.0]
"""


def test_remeshed_lengths_are_the_cases_divided_by_sqrt2_per_level(tmp_path):
    name, levels = remesh_lengths("phantom-indenter-quarter", levels=4)
    assert name == "phantom-quarter" and REMESH_RATIO == SQRT2
    # the case file's [mesh] table: 6 sqrt 2, 3.2 sqrt 2 and 1.6 mm
    case = {"size": 8.485281374238571, "site_size": 4.525483399593905, "path_size": 1.6}
    for k, lv in enumerate(levels):
        assert lv == pytest.approx({key: v / SQRT2 ** k for key, v in case.items()}, rel=1e-15)
    assert levels[2]["size"] == pytest.approx(case["size"] / 2, rel=1e-15)
    # a --size override scales the same way; path_reach (the refined paths' extent) stays
    case_file = tmp_path / "reach.toml"
    case_file.write_text(BOX.replace('builtin = "box"\nsize = 5.0',
                                     'builtin = "phantom"\nsize = 6.0\nsite_size = 3.2\n'
                                     'path_size = 1.6\npath_reach = 4.0\nbase_rim_size = 2.0'))
    _, levels = remesh_lengths(case_file, levels=3, size=12.0)
    assert [lv["size"] for lv in levels] == pytest.approx([12.0, 12.0 / SQRT2, 6.0])
    assert [lv["base_rim_size"] for lv in levels] == pytest.approx([2.0, 2.0 / SQRT2, 1.0])
    assert {lv["path_reach"] for lv in levels} == {4.0}


def test_remeshed_study_builds_each_level_and_assesses_with_ratio_sqrt2(tmp_path, capsys,
                                                                       monkeypatch):
    case = tmp_path / "box.toml"
    case.write_text(BOX)
    built, ratios = [], []
    real_build, real_assess = convergence.build, richardson.assess

    def build(name, size, **kw):
        built.append((name, size, kw))
        return real_build(name, size, **kw)

    def assess(*a, **kw):
        ratios.append(kw.get("ratio"))
        return real_assess(*a, **kw)

    monkeypatch.setattr(convergence, "build", build)
    monkeypatch.setattr(convergence, "assess", assess)
    monkeypatch.setattr(richardson, "assess", assess)
    assert main(["converge", str(case), "--size", "2", "--levels-by", "remesh", "-q",
                 "--json", str(tmp_path / "c.json")]) == 0
    assert "3 remeshed levels, every cell size divided by 1.414 per level" in \
        capsys.readouterr().out
    # the builder's arguments: the case's size (here --size) over sqrt 2^k
    assert [b[0] for b in built] == ["box"] * 3
    assert [b[1] for b in built] == pytest.approx([2.0, 2.0 / SQRT2, 1.0], rel=1e-15)
    # the Richardson / GCI assessment of every quantity is told the ratio sqrt 2
    assert ratios and all(r == SQRT2 for r in ratios)
    d = json.loads((tmp_path / "c.json").read_text())
    assert d["levels_by"] == "remesh" and d["refinement_ratio"] == SQRT2
    st = d["studies"][0]
    assert [lv["size"] for lv in st["mesh_lengths_mm"]] == pytest.approx([2.0, SQRT2, 1.0])
    assert st["h_mm"][0] / st["h_mm"][1] == pytest.approx(SQRT2, rel=1e-12)
    # independently, the meshes themselves: each level's measured mean edge is sqrt 2 shorter
    # than the previous's within 10 % (gmsh's meshes of the 10 mm box at 2 / 1.41 / 1 mm: 1.38
    # and 1.32; uniform refinement would give 2), and its cells about 2.8 times as many
    e, n = st["mean_edge_mm"], st["n_cells"]
    for k in range(2):
        assert e[k] / e[k + 1] == pytest.approx(SQRT2, rel=0.10)
        assert (n[k + 1] / n[k]) ** (1 / 3) == pytest.approx(SQRT2, rel=0.10)
    assert st["probes"]["M"]["values_mm"][-1] == pytest.approx(0.25, rel=0.05)  # mid-box


def test_remeshed_levels_over_the_cell_limit_are_refused_before_meshing(capsys, monkeypatch):
    def build(*a, **kw):
        raise AssertionError("a mesh was built")

    monkeypatch.setattr(convergence, "build", build)
    assert main(["converge", "phantom-indenter-quarter", "--levels-by", "remesh", "--levels", "7",
                 "--degrees", "2", "--max-cells", "100000"]) == 2
    err = capsys.readouterr().err
    assert "the finest of 7 remeshed levels would have about" in err
    assert "builtin 'phantom-quarter'" in err and "100,000 (max_cells, --max-cells)" in err


def test_remeshed_levels_need_a_builtin_mesh(tmp_path, capsys):
    case = tmp_path / "file.toml"
    case.write_text(BOX.replace('builtin = "box"\nsize = 5.0', 'file = "body.msh"'))
    assert main(["converge", str(case), "--levels-by", "remesh"]) == 2
    err = capsys.readouterr().err
    assert "remeshed levels" in err and "rebuild a builtin mesh" in err and "'body.msh'" in err
    # a ratio is for remeshed levels; uniform refinement halves h
    assert main(["converge", str(tmp_path / "file.toml"), "--ratio", "1.5"]) == 2
    assert "--ratio 1.5: uniform refinement halves h" in capsys.readouterr().err
