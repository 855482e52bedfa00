"""The HTML pages the command line writes are well-formed (page_checks: balanced tags, PNG
images that exist, relative links that exist, units in the headers of numbers) and show what
the run computed: validity, discretization, probes with their error estimates, reactions,
indenters, 3D views and the convergence history of a solve; the closed against the open loop of
mpc; the settings of table1 as a key/value table; the verification report; the values, orders,
GCI and extrapolated values of a convergence study; the settings, probes against time and the
final state of a dynamics run. Last, every page the module wrote is drawn in headless Chromium:
it must load each of its pictures and not come out blank."""
import dataclasses
import html
import json
import re
from pathlib import Path

import numpy as np
import pytest
from browser_checks import render_page, require_browser
from page_checks import PageError, check_page
from test_cli_fuzz import BOX
from test_convergence import CASE_TOML

from tissue_reference.model.case import load_case
from tissue_reference.tissue.cli import main

ROOT = Path(__file__).resolve().parents[1]


# the convergence tests' 2D strip, whose study at 4 levels has quantities inside and outside
# the asymptotic range
STRIP = CASE_TOML.format(builtin="rectangle", size=2.5, value="[1.0, 0.5]", point="[5.0, 5.0]")


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("pages")
    (d / "box.toml").write_text(BOX.format(model="neo-hookean"))
    (d / "lin.toml").write_text(BOX.format(model="linear-elastic"))
    (d / "strip.toml").write_text(STRIP)
    return d


def _run(argv, status=0):
    assert main([str(a) for a in argv]) == status, argv


def _cells(page: str, header: str) -> str:
    """The text of the table row whose row header is ``header``."""
    m = re.search(rf"<th scope='row'>{re.escape(header)}</th><td>([^<]*)</td>", page)
    assert m, header
    return m.group(1)


# --------------------------------------------------------------------------- the checker
def test_the_page_checker_finds_what_is_wrong(tmp_path):
    def bad(body, match):
        p = tmp_path / "p.html"
        p.write_text(f"<!DOCTYPE html><html><head><title>t</title></head><body>{body}"
                     "</body></html>")
        with pytest.raises(PageError, match=match):
            check_page(p)

    bad("<div><p>x</div>", r"</div> at line 1 closes \('p'")
    bad("<div>", "<div> opened at line 1 is never closed")
    bad("<img src='missing.png'>", "no such file beside the page")
    (tmp_path / "fake.png").write_text("not a png")
    bad("<img src='fake.png'>", "not a PNG")
    bad("<img src='data:image/png;base64,aGVsbG8='>", "is not a base64 PNG")
    bad("<a href='nowhere.json'>x</a>", "no such file")
    bad("<table><tr><th>push</th></tr><tr><td>5.0</td></tr></table>",
        r"headers of numbers without a unit: \['push'\]")
    bad("<table><tr><th>k</th><th>v</th></tr><tr><th scope='row'>wall time</th><td>1.5</td>"
        "</tr></table>", r"\['wall time'\]")
    good = tmp_path / "good.html"
    png = "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAAAAAA6fptVAAAACklEQVR4nGNgAAAAAgABSK+kcQAAAABJRU5E" \
          "rkJggg=="
    good.write_text("<!DOCTYPE html><html><head><title>t</title></head><body>"
                    f"<img src='data:image/png;base64,{png}'><br><table><tr><th>push (mm)</th>"
                    "<th>solver</th></tr><tr><td>5</td><td>fem</td></tr></table></body></html>")
    assert check_page(good)["tables"] == 1


# --------------------------------------------------------------------------- tissue solve
def test_a_solve_page_shows_the_answer_its_error_bars_and_pictures(work):
    out = work / "solve"
    _run(["solve", work / "box.toml", "--push", "A1=2", "--estimate", "-q", "--out", out,
          "--json", work / "solve.json"])
    d = json.loads((work / "solve.json").read_text())
    found = check_page(out / "report.html")
    assert found["images"] == ["displacement_view_u.png", "displacement_view_J.png",
                               "displacement_history.png"]
    page = (out / "report.html").read_text()
    assert "<div class='valid'><b>Valid answer</b>" in page
    disc = d["discretization"]
    assert _cells(page, "dofs") == str(disc["dofs"]) and _cells(page, "degree") == "P1"
    assert _cells(page, "E (kPa)") == "6" and _cells(page, "formulation") == "displacement"
    # the probe's value and its estimated error as in the JSON
    ux = d["probes"]["T1"]["displacement"][0]
    est = d["probe_error_estimates"]["T1"]
    row = re.search(r"<tr><td>T1</td>(.*?)</tr>", page).group(1)
    assert f"<td>{ux:+.4f}</td>" in row and f"<td>{est:.2g}</td>" in row
    assert "<th>estimated error (mN)</th>" in page and "reaction" in page.lower()
    # the settings as a key/value table
    assert _cells(page, "newton: max step (mm)") == f"{d['solver_settings']['newton']['max_step_mm']:g}"


def test_a_solve_page_says_why_an_answer_has_no_error_bar(work):
    out = work / "solve_p3"
    _run(["solve", work / "box.toml", "--push", "A1=1", "--degree", "3", "-q", "--out", out,
          "--json", work / "solve_p3.json"])
    d = json.loads((work / "solve_p3.json").read_text())
    assert "probe_error_estimates" not in d and "richest" in d["estimate_note"]
    check_page(out / "report.html")
    assert f"No error estimate: {html.escape(d['estimate_note'], quote=False)}" in \
        (out / "report.html").read_text()


def test_a_folder_in_the_place_of_the_page_is_refused_before_any_work(work, capsys):
    out = work / "clash"
    (out / "report.html").mkdir(parents=True)
    assert main(["solve", str(work / "box.toml"), "--push", "A1=1", "-q", "--out",
                 str(out)]) == 2
    assert "report.html" in capsys.readouterr().err
    assert not (out / "displacement.vtu").exists()


def test_an_invalid_answer_is_shown_as_such(work):
    out = work / "invalid"
    _run(["solve", work / "lin.toml", "--solver", "mass-tensor", "--push", "A1=9", "-q",
          "--out", out], status=1)
    check_page(out / "report.html")
    page = (out / "report.html").read_text()
    assert "<div class='invalid'><b>Not valid</b>: " in page and "inverted cell" in page
    assert "<div class='valid'>" not in page


def test_an_admm_page_plots_the_iterations(work):
    out = work / "admm"
    _run(["solve", work / "box.toml", "--push", "A1=1", "--solver", "admm", "-q", "--out", out])
    found = check_page(out / "report.html")
    assert "displacement_history.png" in found["images"]
    assert (out / "displacement_history.png").stat().st_size > 5000


def test_not_converged_indenters_and_warnings_are_on_the_page(work):
    """A last converged state (load fraction below 1), its indenters and warnings, drawn from a
    real solve's result with those entries (the library call the CLI makes)."""
    import tissue_reference.fem_reference as fr
    from tissue_reference.tissue.solve_report import write_solve_report

    case = load_case(work / "box.toml").with_pushes({"A1": 1.0})
    res = fr.solve(case, pushes={"A1": 1.0})
    last = dataclasses.replace(
        res, converged=False, extra={**res.extra, "load_fraction": 0.5},
        warnings=("patch A1 is glued",),
        indenters={"I1": {"push": 3.0, "force": 12.5, "contact_area": 4.25,
                          "max_penetration": 0.01}})
    out = work / "not_converged"
    path = write_solve_report(case, last, out, stem="last_converged", use_pyvista=False)
    check_page(path)
    page = path.read_text()
    assert "<b>Not converged</b>: the last converged state at load fraction 0.5000" in page
    assert "<li>patch A1 is glued</li>" in page
    assert "<th>contact area (mm²)</th>" in page and "<td>4.25</td>" in page
    assert (out / "last_converged_view_J.png").is_file()


def test_the_page_is_written_whole_or_not_at_all(work, tmp_path, monkeypatch):
    import tissue_reference.fem_reference as fr
    import tissue_reference.tissue.solve_report as sr

    case = load_case(work / "box.toml")
    res = fr.solve(case, pushes={"A1": 1.0})

    def broken(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(sr, "_history_plot", broken)
    with pytest.raises(KeyboardInterrupt):
        sr.write_solve_report(case.with_pushes({"A1": 1.0}), res, tmp_path, use_pyvista=False)
    assert not (tmp_path / "report.html").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_vertex_J_is_the_smallest_of_the_cells_around_a_vertex(work):
    from tissue_reference.tissue.solve_report import vertex_min_J

    case = load_case(work / "box.toml")
    assert np.allclose(vertex_min_J(case.mesh, np.zeros_like(case.mesh.points)), 1.0)
    u = np.zeros_like(case.mesh.points)
    u[:, 0] = -0.5 * case.mesh.points[:, 0]                  # x halved everywhere: J = 0.5
    assert np.allclose(vertex_min_J(case.mesh, u), 0.5)


# --------------------------------------------------------------------------- mpc, table1
def test_an_mpc_page_compares_the_closed_and_the_open_loop(work):
    out = work / "mpc"
    # the seed's 5 mm task pushes the box's glued patch past its radius: exit status 1
    _run(["mpc", work / "box.toml", "--target", "T1", "--task", "1", "--steps", "3", "-q",
          "--out", out, "--json", work / "m.json"], status=1)
    d = json.loads((work / "m.json").read_text())
    found = check_page(out / "mpc_T1_task1.html")
    assert found["images"] == ["mpc_T1_task1.png", "mpc_T1_task1_error.png"]
    page = (out / "mpc_T1_task1.html").read_text()
    closed = re.search(r"<tr><td>closed loop \(MPC\)</td>(.*?)</tr>", page).group(1)
    opened = re.search(r"<tr><td>open loop \(eq. 22\)</td>(.*?)</tr>", page).group(1)
    assert f"<td>{d['itae']:.4g}</td>" in closed
    assert f"<td>{d['open_loop']['status']}</td><td>{d['open_loop']['itae']:.4g}</td>" in opened
    assert _cells(page, "horizon") == "5" and _cells(page, "dt (s)") == "1"
    assert _cells(page, "plant material: E (kPa)") == "6"
    assert d["status"] == "outside range" and d["open_loop"]["status"] == "outside range"
    assert "<b>Outside the range where answers converge</b>: plant: glued patch 'A1'" in \
        html.unescape(page)
    assert "its ITAE is no baseline" in page


def test_an_unreachable_goal_gets_a_page_that_says_so(work):
    out = work / "mpc2"
    _run(["mpc", work / "box.toml", "--target", "T1", "--task", "2", "--steps", "3", "-q",
          "--out", out], status=2)
    check_page(out / "mpc_T1_task2.html")
    page = (out / "mpc_T1_task2.html").read_text()
    assert "<b>Unreachable goal</b>" in page and "positive span" in page


def test_table1_pages_show_settings_as_a_table_and_every_plot(work):
    out = work / "t"
    _run(["table1", work / "box.toml", "--steps", "3", "-q", "--task-mm", "2", "--scenarios",
          "gravity", "--out", out])
    found = check_page(out / "table1_scenarios.html")
    assert found["images"] == ["table1_scenarios.png"]
    assert found["links"] == ["gravity/table1.html"]
    found = check_page(out / "gravity" / "table1.html")
    pngs = sorted(p.name for p in (out / "gravity").glob("*.png"))
    assert pngs and sorted(found["images"]) == pngs      # every plot written is on the page
    page = (out / "gravity" / "table1.html").read_text()
    assert "<pre>" not in page and _cells(page, "settings: horizon") == "5"
    assert _cells(page, "settings: q (1/mm²)") == "3"
    assert "<th>Closed-loop ITAE (mm·s²)</th>" in page


# --------------------------------------------------------------------------- verify, suite
def test_the_verify_and_suite_pages_are_well_formed(work):
    _run(["verify", work / "box.toml", "--push", "A1=1", "-q", "--out", work / "v"])
    found = check_page(work / "v" / "report.html")
    assert found["images"] and found["tables"] >= 3
    _run(["suite", "--solvers", "fem", "--problems", "shear-patch", "-q", "--out",
          work / "s"])
    check_page(work / "s" / "suite.html")


PLUGIN = """
import numpy as np


def solve(case, pushes, **options):
    return {{"u": np.full((case.mesh.n_vertices, case.mesh.gdim), {shift}),
             "history": {{"iteration": [1, 2, 3], "max_step_mm": [0.1, 0.01, 0.001]}}}}
"""


def test_a_verify_page_links_the_plot_of_every_plugin_it_wrote(work):
    """Two plugins named by files of one name in two folders (path/to/plugin.py:solve): each
    plot is written beside the page under a name of its own without folders or colons, the
    page shows every plot it wrote and links nothing else."""
    names = []
    for k, folder in enumerate(("first", "second")):
        (work / folder).mkdir()
        (work / folder / "plugin.py").write_text(PLUGIN.format(shift=0.001 * (k + 1)))
        names.append(f"{work / folder / 'plugin.py'}:solve")
    out = work / "v_plugins"
    _run(["verify", work / "box.toml", "--push", "A1=1", "-q", "--solvers", "mass-tensor",
          *names, "--out", out])
    found = check_page(out / "report.html")         # every <img> a PNG beside the page
    written = sorted(p.name for p in out.iterdir() if p.suffix == ".png")
    assert sorted(found["images"]) == written and len(written) == 3
    assert all(p.is_file() for p in out.iterdir())  # no folders made from a plugin's path
    assert "convergence_mass-tensor.png" in written
    for png in written:
        assert re.fullmatch(r"convergence_[A-Za-z0-9][A-Za-z0-9._-]*\.png", png), png
    page = (out / "report.html").read_text()
    assert "<th>H1 seminorm error (mm/mm)</th>" in page
    assert page.count("<h3>") == 3 and all(html.escape(n) in page for n in names)


def test_the_reference_records_every_newton_iterate_for_the_plot():
    import tissue_reference.fem_reference as fr

    case = load_case(ROOT / "meshes" / "cases" / "phantom.toml", size=14)
    h = fr.solve(case, pushes={"A1": 15.0}).history      # several load steps
    assert len(h["load_fraction"]) > 1
    assert len(h["iterate_residual"]) == len(h["iterate_load"]) >= sum(h["newton_iterations"])
    assert h["iterate_residual"][-1] == h["residual"][-1]
    assert h["iterate_load"][-1] == 1.0 and set(h["load_fraction"]) <= set(h["iterate_load"])
    # the residual falls within each load step
    first = h["iterate_load"].index(1.0)
    assert h["iterate_residual"][-1] < 1e-6 * h["iterate_residual"][first]


# --------------------------------------------------------------------------- converge, dynamics
def _row(section: str, *first) -> list:
    """The cells of the table row of ``section`` that starts with the cells ``first``."""
    head = "".join(f"<td>{html.escape(c)}</td>" for c in first)
    m = re.search(rf"<tr>{re.escape(head)}(.*?)</tr>", section)
    assert m, first
    return re.findall(r"<td>([^<]*)</td>", m.group(1))


def test_a_convergence_page_shows_every_value_order_gci_and_extrapolation(work):
    from tissue_reference.meshes.html_page import fmt
    from tissue_reference.tissue.converge_report import NO_EXTRAPOLATION

    out = work / "converge"
    _run(["converge", work / "strip.toml", "--levels", "4", "--degrees", "1", "2", "-q", "--out",
          out])
    d = json.loads((out / "convergence.json").read_text())
    found = check_page(out / "report.html")
    assert found["images"] == ["convergence.png"]
    page = (out / "report.html").read_text()
    sections = page.split("<h2>Degree ")[1:]
    assert len(sections) == len(d["studies"]) == 2
    seen = {True: 0, False: 0}
    for sec, st in zip(sections, d["studies"]):
        assert sec.startswith(f"{st['degree']}: P{st['degree']} displacement")
        for k, h in enumerate(st["h_mm"]):
            assert _row(sec, str(k))[:3] == [fmt(h, 4), str(st["n_cells"][k]),
                                            str(st["n_dofs"][k])]
            assert f"<th>u at h = {fmt(h, 3)} mm (mm)</th>" in sec
            assert f"<th>F at h = {fmt(h, 3)} mm (mN)</th>" in sec
        for group, unit in (("probes", "mm"), ("reactions", "mN")):
            for name, vec in st[group].items():
                for comp, q in vec["components"].items():
                    cells = _row(sec, name, comp)
                    n = len(q[f"values_{unit}"])
                    assert cells[:n] == [fmt(v, 6) for v in q[f"values_{unit}"]]
                    order, _, asym, extra, g, g_rel = cells[n:]
                    assert order == fmt(q["observed_order"], 3)
                    assert asym == ("yes" if q["asymptotic"] else "no")
                    assert extra == (fmt(q[f"extrapolated_{unit}"], 6) if q["asymptotic"]
                                     else NO_EXTRAPOLATION)
                    assert g == fmt(q[f"gci_{unit}"], 3)
                    assert g_rel == fmt(100 * q["gci_rel"], 3)
                    seen[q["asymptotic"]] += 1
    assert seen[True] and seen[False]          # both kinds of row are on the page
    assert _cells(page, "material: E (kPa)") == "6" and _cells(page, "levels") == "4"


def test_a_dynamics_page_shows_the_settings_the_probes_and_the_final_state(work):
    out = work / "dynamics"
    _run(["dynamics", work / "box.toml", "--dt", "0.01", "--steps", "3", "--push", "A1=1",
          "--gravity", "0", "0", "-9810", "-q", "--out", out, "--json", work / "dyn.json"])
    d = json.loads((work / "dyn.json").read_text())
    found = check_page(out / "report.html")
    assert found["images"] == ["dynamics_history.png", "final_view_u.png"]
    assert found["links"] == ["trajectory.pvd", "displacement.xdmf", "displacement.vtu"]
    for png in found["images"]:
        assert (out / png).stat().st_size > 10_000
    page = (out / "report.html").read_text()
    assert "<div class='valid'><b>Valid answer</b>" in page
    assert f"min J {d['final']['min_J']:.4g}" in page
    assert _cells(page, "time step dt (s)") == "0.01" and _cells(page, "steps") == "3"
    assert _cells(page, "mass") == "lumped" and _cells(page, "gravity (mm/s²)") == "[0, 0, -9810]"
    assert _cells(page, "final time (s)") == f"{d['times_s'][-1]:.4g}"
    assert _cells(page, "total mass (kg)") == f"{d['total_mass_kg']:.4g}"
    assert _cells(page, "final kinetic energy (µJ)") == f"{d['kinetic_energy_uJ'][-1]:.4g}"
    assert _cells(page, "steps converged") == "3 of 3"
    final = np.asarray(d["probes"]["T1"][-1])
    assert d["final"]["probes"]["T1"]["displacement"] == pytest.approx(final.tolist())
    assert _row(page, "T1")[:4] == [*(f"{x:+.4f}" for x in final),
                                    f"{np.linalg.norm(final):.4f}"]


def test_a_folder_in_the_place_of_a_converge_or_dynamics_page_is_refused(work, capsys):
    for argv in (["converge", work / "strip.toml", "--levels", "3"],
                 ["dynamics", work / "box.toml", "--dt", "0.01", "--steps", "1"]):
        out = work / f"clash_{argv[0]}"
        (out / "report.html").mkdir(parents=True)
        assert main([str(a) for a in argv] + ["-q", "--out", str(out)]) == 2, argv
        assert "report.html" in capsys.readouterr().err
        assert sorted(p.name for p in out.iterdir()) == ["report.html"]


# --------------------------------------------------------------------------- in a browser
def test_every_page_renders_in_a_headless_browser(work, tmp_path):
    """The pages the tests above wrote (run with them): each drawn without error, not blank,
    every picture loaded."""
    exe = require_browser()
    pages = sorted(p for p in work.rglob("*.html") if p.is_file())
    assert len(pages) >= 12, f"only {len(pages)} pages: run the whole module, whose tests " \
                             "write the pages this one draws"
    for k, page in enumerate(pages):
        found = check_page(page)
        drawn = render_page(page, exe, tmp_path / f"page{k}.png")
        assert len(drawn["image_widths"]) == len(found["images"]), page
