"""The Mass Tensor Method against the linear reference it is verified with, per mesh size, in one
run: the glued phantom, A1 pushed 4 mm then 3.5 mm (another push on the same point types; within
the patch's radius, where every cell of the linear answers stays valid).

Per size: the linear reference (dolfinx P1, its kept solver: timed on a second call, as ``tissue
verify`` times it); the Mass Tensor direct solve (the default: one factorization of the
projected tensors, CHOLMOD through the ``factorize`` hook as the command line passes it) cold
(tensors and factorization built in the call) and warm (the next push: the model's kept
factorization, a back-substitution); the AMG-preconditioned conjugate gradients (method "amg",
stopped when the distance still to go, estimated from the contraction of its moves, is below
0.01 mm) cold (tensors and AMG hierarchy built in the call) and warm (the hierarchy kept); PCG
stopped by the seed's 0.01 mm rule. Each with its largest vertex distance from the reference
(mm) and the ratio reference time / its time; and the memory the model keeps for its solves
(the direct solve's factor, the AMG hierarchy).

    .venv/bin/python bench/bench_mass_tensor_speed.py [--sizes 10 6 2.8 1.8]
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from tissue_reference.fem_reference import cholmod_factor
from tissue_reference.fem_reference import solve as reference_solve
from tissue_reference.meshes.answer_warnings import TissueWarning
from tissue_reference.meshes.case import load_case
from tissue_reference.solvers import mass_tensor as mt
from tissue_reference.solvers.mass_tensor import driver


def _timed(f):
    t0 = time.perf_counter()
    r = f()
    return r, time.perf_counter() - t0


def kept_mib() -> float:
    """MiB the cached Mass Tensor model keeps for its solves: CHOLMOD's (SuperLU's) factor
    entries, or the AMG hierarchy's matrices and its coarsest level's factor; 12 bytes per
    entry (value and index)."""
    total = 0
    for model in driver.MODEL_CACHE.values():
        for kept in model._factors.values():
            if hasattr(kept, "ksp"):   # CHOLMOD through PETSc
                total += 12 * kept.ksp.getPC().getFactorMatrix().getInfo()["nz_used"]
            elif hasattr(kept, "vcycle"):   # the AMG hierarchy and its coarsest factor
                total += kept.nbytes
            else:   # SuperLU
                total += 12 * (kept.L.nnz + kept.U.nnz)
    return total / 2 ** 20


def row(size: float, pushes=(4.0, 3.5)) -> None:
    case = load_case("phantom", size=size).with_material(model="linear-elastic")
    ref_t, refs = [], {}
    for p in pushes:
        reference_solve(case, pushes={"A1": p}, degree=1)            # first call: compiles
        refs[p], t = _timed(lambda p=p: reference_solve(case, pushes={"A1": p}, degree=1))
        ref_t.append(t)
    driver.MODEL_CACHE.clear()                                           # a cold Mass Tensor model
    cold, t_cold = _timed(lambda: mt.solve(case, pushes={"A1": pushes[0]},
                                           factorize=cholmod_factor))
    warm, t_warm = _timed(lambda: mt.solve(case, pushes={"A1": pushes[1]},
                                           factorize=cholmod_factor))
    direct_mib = kept_mib()
    pcg, t_pcg = _timed(lambda: mt.solve(case, pushes={"A1": pushes[1]}, method="pcg",
                                         stop_mm=0.01))
    driver.MODEL_CACHE.clear()
    amg0, t_amg0 = _timed(lambda: mt.solve(case, pushes={"A1": pushes[0]}, method="amg",
                                           stop_mm=0.01))
    amg1, t_amg1 = _timed(lambda: mt.solve(case, pushes={"A1": pushes[1]}, method="amg",
                                           stop_mm=0.01))
    amg_mib = kept_mib()

    def err(res, p):
        return float(np.linalg.norm(res.u - refs[p].u, axis=1).max())

    valid = all(r.valid is not False for r in (*refs.values(), cold, warm, pcg, amg0, amg1))

    r0, r1 = ref_t
    print(f"{case.mesh.n_cells:8d} tets  reference {r0:7.3f} / {r1:7.3f} s  |  "
          f"direct cold {t_cold:7.3f} s x{r0 / t_cold:5.1f} ({err(cold, pushes[0]):.1e} mm)  "
          f"warm {t_warm:7.3f} s x{r1 / t_warm:5.1f} ({err(warm, pushes[1]):.1e} mm)  |  "
          f"pcg 0.01 mm rule {pcg.iterations:4d} its {t_pcg:7.3f} s x{r1 / t_pcg:5.1f} "
          f"({err(pcg, pushes[1]):.1e} mm)  |  amg to 0.01 mm cold {amg0.iterations:3d} its "
          f"{t_amg0:7.3f} s x{r0 / t_amg0:5.1f} ({err(amg0, pushes[0]):.1e} mm)  warm "
          f"{amg1.iterations:3d} its {t_amg1:7.3f} s x{r1 / t_amg1:5.1f} "
          f"({err(amg1, pushes[1]):.1e} mm)  |  kept: factor {direct_mib:.1f} MiB, AMG "
          f"{amg_mib:.1f} MiB{'' if valid else '  (an answer is not valid)'}",
          flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[10.0, 6.0, 2.8, 1.8])
    a = ap.parse_args()
    warnings.simplefilter("ignore", TissueWarning)   # each answer's validity is in its result
    print("glued phantom, linear elasticity E = 6 kPa, nu = 0.45; A1 = 4 mm, then 3.5 mm; "
          "x = reference time / Mass Tensor time (same push)")
    for s in a.sizes:
        row(s)


if __name__ == "__main__":
    main()
