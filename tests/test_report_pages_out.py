"""The pages of the commands whose --out folder held only data and pictures: manipulability
(the maps, per task the median index or that it is reachable nowhere), jacobian (J with the
finite-difference check, the state, |J| drawn) and implant (the plan, the mesh, the solve, the
surface distances, the distance picture). Each is well-formed (page_checks) and shows the
numbers of the JSON the same run wrote."""
import json
import re

import numpy as np
import pytest
from browser_checks import render_page, require_browser
from page_checks import check_page
from test_cli_fuzz import BOX

from tissue_reference.meshes.html_page import fmt
from tissue_reference.tissue.cli import main
from tissue_reference.tissue.implant_report import NO_ICP


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("pages_out")
    (d / "box.toml").write_text(BOX.format(model="neo-hookean"))
    return d


def _run(argv, status=0):
    assert main([str(a) for a in argv]) == status, argv


def _row(page: str, first: str) -> list[str]:
    """The cells of the table row whose first cell is ``first``."""
    m = re.search(rf"<tr><(?:td|th scope='row')>{re.escape(first)}</t[dh]>(.*?)</tr>", page)
    assert m, first
    return re.findall(r"<td[^>]*>(.*?)</td>", m.group(1))


# --------------------------------------------------------------------------- manipulability
def test_a_manipulability_page_shows_each_tasks_median_or_that_it_is_reachable_nowhere(work):
    out = work / "maps"
    _run(["manipulability", work / "box.toml", "--compare", "--plane-z", "5", "--spacing", "2.5",
          "-q", "--out", out])
    found = check_page(out / "report.html")
    assert found["images"] == ["manipulability.png"]
    d = json.loads((out / "manipulability_box.json").read_text())
    page = (out / "report.html").read_text()
    for t in (1, 2, 3):
        v = np.array([np.nan if x is None else x for row in d[f"task{t}"]["index"] for x in row])
        cells = _row(page, str(t))
        assert cells[2] == str(int(np.isfinite(v).sum()))
        if np.isfinite(v).any():
            assert cells[3] == fmt(float(np.median(v[np.isfinite(v)])))
            assert cells[4] == fmt(float(np.nanmax(v)))
        else:
            assert cells[3] == "reachable nowhere"
    # the box's one actuator pushes along -x: task 3 (+x, +y) is out of its reach everywhere
    assert "Task 3 (x +5, y +5 mm) is reachable nowhere" in page
    assert "<th>median index (mm/mm)</th>" in page
    assert re.search(r"<th scope='row'>spacing \(mm\)</th><td>2.5</td>", page)
    assert re.search(r"<th scope='row'>material: E \(kPa\)</th><td>6</td>", page)


def test_a_folder_in_the_place_of_the_maps_page_is_refused_before_any_work(work, capsys):
    out = work / "maps_clash"
    (out / "report.html").mkdir(parents=True)
    assert main(["manipulability", str(work / "box.toml"), "--compare", "--plane-z", "5",
                 "--out", str(out)]) == 2
    assert "report.html" in capsys.readouterr().err
    assert not list(out.glob("manipulability*"))


# --------------------------------------------------------------------------- jacobian
def test_a_jacobian_page_shows_J_its_check_the_state_and_the_kind(work):
    out = work / "jac"
    _run(["jacobian", work / "box.toml", "--state-push", "A1=1", "-q", "--json",
          work / "j.json", "--out", out])
    d = json.loads((work / "j.json").read_text())
    assert json.loads((out / "jacobian.json").read_text()) == d
    assert d["actuator_kind"] == "glued patch" and d["fd_max_rel_error"] < 1e-3
    found = check_page(out / "report.html")
    assert found["images"] == ["jacobian.png"]
    page = (out / "report.html").read_text()
    assert "<th>A1 (mm/mm)</th>" in page and "<div class='valid'>" in page
    for name, row in zip(d["rows"], d["J"]):
        assert _row(page, name) == [fmt(v) for v in row]
    assert _row(page, "largest difference to central differences (relative)") == \
        [fmt(d["fd_max_rel_error"])]
    assert _row(page, "central-difference step (mm)") == ["0.02"]
    assert _row(page, "A1") == ["1", "yes"]
    assert "Actuator kind: <b>glued patch</b>" in page


def test_jacobian_out_is_checked_before_any_work(work, capsys):
    out = work / "jac_clash"
    (out / "report.html").mkdir(parents=True)
    assert main(["jacobian", str(work / "box.toml"), "--json", str(work / "j2.json"),
                 "--out", str(out)]) == 2
    assert "report.html" in capsys.readouterr().err
    assert not (work / "j2.json").exists() and not (out / "jacobian.json").exists()


# --------------------------------------------------------------------------- implant
def _implant_page(d: dict, out):
    found = check_page(out / "report.html")
    page = (out / "report.html").read_text()
    assert _row(page, "implant shape") == [d["implant"]["shape"]]
    assert _row(page, "side") == [d["implant"]["side"]]
    assert _row(page, "volume (cm³)") == [fmt(d["implant"]["volume_cc"])]
    assert _row(page, "base width (mm)") == [fmt(d["implant_dimensions_mm"][0])]
    assert _row(page, "tetrahedra (count)") == [str(d["n_cells"])]
    assert _row(page, "target points (count)") == [str(d["points"]["target"])]
    assert _row(page, "Mass Tensor iterations (count)") == [str(d["iterations"])]
    return found, page


def test_an_implant_page_shows_the_plan_the_solve_and_the_distances(work, monkeypatch):
    monkeypatch.chdir(work)       # a relative --out: the picture lands beside the page
    _run(["implant", "--synthetic", "--volume", "200", "--side", "right", "-q", "--json",
          "i.json", "--out", "imp"])
    d = json.loads((work / "i.json").read_text())
    found, page = _implant_page(d, work / "imp")
    assert found["images"] == ["skin_distance.png"]
    assert (work / "imp" / "skin_distance.png").read_bytes()[:4] == b"\x89PNG"
    assert _row(page, "Mass Tensor vs the linear FEM reference") == \
        [fmt(d["d_max_mm"]), fmt(d["mean_distance_mm"]), NO_ICP, NO_ICP]   # one mesh: no ICP
    assert "<th>d_max (mm)</th><th>mean distance (mm)</th>" in page
    assert set(found["links"]) == {"tissue.vtu", "implant.vtu", "skin_distance.vtu"}


def test_an_implant_page_without_the_reference_says_there_are_no_distances(work, capsys):
    out = work / "imp_noref"
    (out / "report.html").mkdir(parents=True)
    assert main(["implant", "--synthetic", "--no-reference", "-q", "--json",
                 str(work / "i2.json"), "--out", str(out)]) == 2
    assert "report.html" in capsys.readouterr().err and not (work / "i2.json").exists()
    (out / "report.html").rmdir()
    _run(["implant", "--synthetic", "--no-reference", "-q", "--json", work / "i2.json",
          "--out", out])
    d = json.loads((work / "i2.json").read_text())
    found, page = _implant_page(d, out)
    assert found["images"] == [] and "No surface distances" in page


def test_these_pages_render_in_a_headless_browser(work, tmp_path):
    """The maps, Jacobian and implant pages the tests above wrote (run with them): each drawn
    without error, not blank, every picture loaded."""
    exe = require_browser()
    pages = sorted(p for p in work.rglob("report.html") if p.is_file())
    assert len(pages) >= 3, f"only {len(pages)} pages: run the whole module"
    for k, page in enumerate(pages):
        found = check_page(page)
        drawn = render_page(page, exe, tmp_path / f"page{k}.png")
        assert len(drawn["image_widths"]) == len(found["images"]), page
