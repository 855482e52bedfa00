"""The Mass Tensor Method against the linear reference it is verified with, per mesh size, in one
run: the glued phantom, A1 pushed 4 mm then 3.5 mm (another push on the same point types; within
the patch's radius, where every cell of the linear answers stays valid).

Per size: the linear reference (dolfinx P1, its kept solver: timed on later calls, as ``tissue
verify`` times it); the Mass Tensor direct solve (the default: one factorization of the
projected tensors, CHOLMOD through the ``factorize`` hook as the command line passes it) cold
(tensors and factorization built in the call) and warm (the next push: the model's kept
factorization, a back-substitution); the AMG-preconditioned conjugate gradients (method "amg",
stopped when the distance still to go, estimated from the contraction of its moves, is below
0.01 mm) cold (tensors and AMG hierarchy built in the call) and warm (the hierarchy kept); PCG
stopped by the seed's 0.01 mm rule. Each with its largest vertex distance from the reference
(mm) and the ratio reference time / its time; and the memory the model keeps for its solves
(the direct solve's factor, the AMG hierarchy).

Every time is the best of ``--repeat`` runs (a cold run starts from an empty model cache each
time). The mesh's edges and the pattern of its tensors' matrix (``MeshData.edge_topology``) are
the mesh's, computed once per mesh as the reference computes its dof map and sparsity pattern
once: a cold solve does not rebuild them; their time is printed on its own ("mesh edges").

    .venv/bin/python bench/bench_mass_tensor_speed.py [--sizes 10 6 2.8 1.8] [--repeat 3]
"""
from __future__ import annotations

import argparse
import warnings

import numpy as np
from _timing import best  # this folder's

from tissue_reference.fem_reference import cholmod_factor
from tissue_reference.fem_reference import solve as reference_solve
from tissue_reference.meshes.mesh import edge_topology
from tissue_reference.model.answer_warnings import TissueWarning
from tissue_reference.model.case import load_case
from tissue_reference.solvers import mass_tensor as mt
from tissue_reference.solvers.mass_tensor import driver


def kept_mib() -> float:
    """MiB the cached Mass Tensor model keeps for its solves (``MassTensorModel.kept_bytes``)."""
    return sum(m.kept_bytes() for m in driver.MODEL_CACHE.values()) / 2 ** 20


def row(size: float, repeat: int, pushes=(4.0, 3.5)) -> None:
    case = load_case("phantom", size=size).with_material(model="linear-elastic")
    _, t_topo = best(lambda: edge_topology(case.mesh.cells, case.mesh.n_vertices), repeat)
    edges = len(case.mesh.edge_topology.edges)   # the mesh's, made once and kept
    ref_t, refs = [], {}
    for p in pushes:
        reference_solve(case, pushes={"A1": p}, degree=1)            # first call: compiles
        refs[p], t = best(lambda p=p: reference_solve(case, pushes={"A1": p}, degree=1), repeat)
        ref_t.append(t)

    def cold(**kw):   # best of `repeat` first solves, each from an empty model cache
        return best(lambda: mt.solve(case, pushes={"A1": pushes[0]}, **kw), repeat,
                     before=driver.MODEL_CACHE.clear)

    def warm(**kw):   # the next push, on the model the last cold solve left
        return best(lambda: mt.solve(case, pushes={"A1": pushes[1]}, **kw), repeat)

    cold_d, t_cold = cold(factorize=cholmod_factor)
    warm_d, t_warm = warm(factorize=cholmod_factor)
    direct_mib = kept_mib()
    pcg, t_pcg = warm(method="pcg", stop_mm=0.01)
    amg0, t_amg0 = cold(method="amg", stop_mm=0.01)
    amg1, t_amg1 = warm(method="amg", stop_mm=0.01)
    amg_mib = kept_mib()

    def err(res, p):
        return float(np.linalg.norm(res.u - refs[p].u, axis=1).max())

    valid = all(r.valid is not False for r in (*refs.values(), cold_d, warm_d, pcg, amg0, amg1))

    r0, r1 = ref_t
    print(f"{case.mesh.n_cells:8d} tets  mesh edges ({edges}) {t_topo:7.3f} s  reference {r0:7.3f} / "
          f"{r1:7.3f} s  |  direct cold {t_cold:7.3f} s x{r0 / t_cold:5.1f} "
          f"({err(cold_d, pushes[0]):.1e} mm)  warm {t_warm:7.3f} s x{r1 / t_warm:5.1f} "
          f"({err(warm_d, pushes[1]):.1e} mm)  |  pcg 0.01 mm rule {pcg.iterations:4d} its "
          f"{t_pcg:7.3f} s x{r1 / t_pcg:5.1f} ({err(pcg, pushes[1]):.1e} mm)  |  amg to 0.01 mm "
          f"cold {amg0.iterations:3d} its {t_amg0:7.3f} s x{r0 / t_amg0:5.1f} "
          f"({err(amg0, pushes[0]):.1e} mm; with the mesh edges x{r0 / (t_amg0 + t_topo):4.1f})"
          f"  warm {amg1.iterations:3d} its {t_amg1:7.3f} s x{r1 / t_amg1:5.1f} "
          f"({err(amg1, pushes[1]):.1e} mm)  |  kept: factor {direct_mib:.1f} MiB, AMG "
          f"{amg_mib:.1f} MiB{'' if valid else '  (an answer is not valid)'}",
          flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[10.0, 6.0, 2.8, 1.8])
    ap.add_argument("--repeat", type=int, default=3, help="each time is the best of this many runs")
    a = ap.parse_args()
    warnings.simplefilter("ignore", TissueWarning)   # each answer's validity is in its result
    print("glued phantom, linear elasticity E = 6 kPa, nu = 0.45; A1 = 4 mm, then 3.5 mm; "
          "x = reference time / Mass Tensor time (same push)")
    for s in a.sizes:
        row(s, a.repeat)


if __name__ == "__main__":
    main()
