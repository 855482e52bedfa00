"""Mesh-refinement study of the reference: probe displacements against h, observed order,
Richardson-extrapolated values. Units mm."""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np

from meshes.builders import build
from meshes.case import Case

from .solver import ReferenceSolver

__all__ = ["ConvergenceStudy", "observed_order", "refinement_study"]


@dataclass(frozen=True)
class ConvergenceStudy:
    degree: int
    sizes: list           # h, mm (coarse to fine)
    n_cells: list
    probes: dict          # name -> (levels, gdim) displacement, mm
    order: dict           # name -> observed order from the three finest levels (nan if undefined)
    extrapolated: dict    # name -> Richardson-extrapolated displacement, mm


def observed_order(q_coarse, q_mid, q_fine, ratio=2.0) -> float:
    """p = log(|q1 - q2| / |q2 - q3|) / log(ratio) for norms of vector differences."""
    a = np.linalg.norm(np.asarray(q_coarse) - q_mid)
    b = np.linalg.norm(np.asarray(q_mid) - q_fine)
    if a == 0 or b == 0:
        return float("nan")
    return math.log(a / b) / math.log(ratio)


def refinement_study(case: Case, builder: str, *, coarsest: float = 16.0, levels: int = 4,
                     degree: int = 1, pushes=None, progress=False) -> ConvergenceStudy:
    """Solve ``case`` on meshes of ``builder`` with sizes coarsest / 2^k, k < levels."""
    sizes = [coarsest / 2 ** k for k in range(levels)]
    probes = {p.name: [] for p in case.probes}
    cells = []
    for h in sizes:
        c = case.with_mesh(build(builder, h))
        res = ReferenceSolver(c, degree=degree).solve(pushes)
        cells.append(c.mesh.n_cells)
        for k, v in res.probes.items():
            probes[k].append(np.asarray(v))
        if progress:
            print(f"tissue converge: degree {degree} h={h:g} mm, {c.mesh.n_cells} cells, "
                  f"{res.iterations} Newton iterations, {res.wall_time_s:.1f} s", file=sys.stderr,
                  flush=True)
    order, extra = {}, {}
    for k, q in probes.items():
        q = np.array(q)
        probes[k] = q
        if len(q) >= 3:
            p = observed_order(q[-3], q[-2], q[-1])
            order[k] = p
            extra[k] = q[-1] + (q[-1] - q[-2]) / (2 ** p - 1) if np.isfinite(p) and p > 0 else q[-1]
        else:
            order[k] = float("nan")
            extra[k] = q[-1]
    return ConvergenceStudy(degree, sizes, cells, probes, order, extra)
