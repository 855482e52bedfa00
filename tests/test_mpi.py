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
           str(degree), "--formulation", formulation, "--push", "A1=8", "--push", "A3=4", "-q",
           "--json", str(out)]
    if nproc > 1:
        cmd = [MPIRUN, "--allow-run-as-root", "--oversubscribe", "-n", str(nproc)] + cmd
    env = {**os.environ, "OMPI_MCA_rmaps_base_oversubscribe": "1"}
    subprocess.run(cmd, check=True, cwd=tmp_path, env=env, capture_output=True, timeout=600)
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
