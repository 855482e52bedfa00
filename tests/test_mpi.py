"""Tier 4: two MPI ranks give the serial answer (probes and reactions, relative 1e-8)."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TISSUE = str(Path(sys.executable).with_name("tissue"))
MPIRUN = shutil.which("mpirun")


def run_solve(tmp_path, name, nproc, degree, formulation="displacement"):
    out = tmp_path / f"{name}.json"
    cmd = [TISSUE, "solve", str(ROOT / "meshes/cases/phantom.toml"), "--size", "14", "--degree",
           str(degree), "--formulation", formulation, "--push", "A1=4", "--push", "A3=2", "-q",
           "--json", str(out)]
    if nproc > 1:
        cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "-n", str(nproc)] + cmd
    env = {**os.environ, "OMPI_MCA_rmaps_base_oversubscribe": "1"}
    r = subprocess.run(cmd, check=False, cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=600)
    output = f"{r.stdout[-2000:]}\n{r.stderr[-4000:]}"
    assert r.returncode == 0, f"{' '.join(cmd)} exited {r.returncode}:\n{output}"
    return json.loads(out.read_text())


@pytest.mark.mpi
@pytest.mark.skipif(MPIRUN is None, reason="mpirun not installed")
@pytest.mark.parametrize("degree,formulation", [(1, "displacement"), (2, "displacement"),
                                                (2, "mixed")])
def test_two_ranks_match_serial(tmp_path, degree, formulation):
    serial = run_solve(tmp_path, "serial", 1, degree, formulation)
    par = run_solve(tmp_path, "mpi", 2, degree, formulation)
    assert serial["discretization"] == par["discretization"]
    assert serial["converged"] and par["converged"]
    for name, p in serial["probes"].items():
        a, b = np.array(p["displacement"]), np.array(par["probes"][name]["displacement"])
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-8 * np.abs(a).max())
    for region, r in serial["reactions"].items():
        a, b = np.array(r), np.array(par["reactions"][region])
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-8 * np.abs(a).max())
    assert par["n_vertices"] == serial["n_vertices"]


@pytest.mark.mpi
@pytest.mark.skipif(MPIRUN is None, reason="mpirun not installed")
def test_two_ranks_match_serial_with_contact(tmp_path):
    """A rigid tip pressed into the half phantom (mirror plane sliding, P2: P1 on 4 mm cells
    lets the tip through): the contact force,
    contact area, penetration and targets of two ranks are the serial ones."""
    text = (ROOT / "meshes/cases/phantom-indenter-half.toml").read_text()
    for old, new in (("size = 6.0 ", "size = 12.0 "), ("site_size = 3.2 ", "site_size = 4.0 "),
                     ("path_size = 1.6 ", "# path_size = 1.6 ")):   # no refined paths at 2 mm
        assert old in text, old
        text = text.replace(old, new)
    case = tmp_path / "half.toml"
    case.write_text(text)
    runs = {}
    for nproc in (1, 2):
        out = tmp_path / f"contact-{nproc}.json"
        cmd = [TISSUE, "solve", str(case), "--push", "A1=2", "--degree", "2", "--no-estimate", "-q",
               "--json", str(out)]
        if nproc > 1:
            cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "-n", str(nproc)] + cmd
        env = {**os.environ, "OMPI_MCA_rmaps_base_oversubscribe": "1"}
        subprocess.run(cmd, check=True, cwd=tmp_path, env=env, capture_output=True,
                       timeout=600)
        runs[nproc] = json.loads(out.read_text())
    serial, par = runs[1], runs[2]
    assert serial["converged"] and par["converged"] and serial["valid"] and par["valid"]
    assert serial["discretization"] == par["discretization"]
    a, b = serial["indenters"]["A1"], par["indenters"]["A1"]
    assert a["force"] > 1.0 and a["contact_area"] > 1.0
    for key in ("force", "contact_area", "max_penetration"):
        assert b[key] == pytest.approx(a[key], rel=1e-7), key
    for name, p in serial["probes"].items():
        x, y = np.array(p["displacement"]), np.array(par["probes"][name]["displacement"])
        np.testing.assert_allclose(y, x, rtol=1e-7, atol=1e-8 * np.abs(x).max())
