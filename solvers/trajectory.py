"""Trajectories of the ADMM's implicit-Euler dynamics (seed 000 eq. 5), step by step, in the
result form the reference's dynamics returns, so the two compare step for step. Units: mm, mm/s,
s, kg, uJ."""
from __future__ import annotations

import sys
import time

import numpy as np

from tissue_reference.model.results import DynamicsResult

from . import admm

__all__ = ["admm_trajectory"]


def admm_trajectory(case, *, dt: float, steps: int, progress: bool = False, **options):
    """The ADMM's implicit Euler (``solvers.admm.solve`` with ``ImplicitEuler``), one call per
    step carrying its state and velocity (the same arithmetic as one ``steps``-step call), as a
    ``model.results.DynamicsResult`` (lumped mass, kg; dt in s; mm, mm/s, uJ), the form the
    reference's ``fem_reference.dynamics.simulate`` returns. ``options`` go to ``admm.solve``
    (e.g. ``factorize=fem_reference.cholmod_factor`` for the Newton polish)."""
    t0 = time.perf_counter()
    n, d = case.mesh.n_vertices, case.mesh.gdim
    mass = admm.prepare(case, dt=dt).mass
    # the start state: rest with the prescribed values (the ADMM's convention)
    u0 = np.zeros((n, d))
    u0.reshape(-1)[case.constraints.dofs] = case.constraints.values
    u = v = None
    us, vel = [u0], [np.zeros((n, d))]
    probes = {k: [np.asarray(p, float)] for k, p in case.probe_values(u0).items()}
    kin, strain, conv, its = [0.0], [admm.strain_energy(case, u0.ravel())], [], []
    res = None
    for k in range(1, steps + 1):
        res = admm.solve(case, initial=u, dynamics=admm.ImplicitEuler(dt=dt, steps=1, velocity=v),
                         **options)
        u, v = res.u, res.extra["velocity"]
        us.append(u)
        vel.append(v)
        for name, p in res.probes.items():
            probes[name].append(np.asarray(p, float))
        kin.append(0.5 * float(v.ravel() @ (mass * v.ravel())))
        strain.append(res.strain_energy)
        conv.append(bool(res.converged))
        its.append(int(res.iterations))
        if progress:
            print(f"tissue admm dynamics: step {k}/{steps} t = {k * dt:.4g} s, "
                  f"{res.extra['admm_iterations']} ADMM + {res.extra['newton_iterations']} "
                  f"Newton iterations, kinetic {kin[-1]:.3e} uJ", file=sys.stderr, flush=True)
    return DynamicsResult(
        times=dt * np.arange(steps + 1), u=np.array(us), velocity=np.array(vel),
        probes={k: np.array(p) for k, p in probes.items()}, kinetic_energy=np.array(kin),
        strain_energy=np.array(strain), converged=np.array(conv, bool),
        iterations=np.array(its, int), wall_time_s=time.perf_counter() - t0,
        dt=float(dt), mass="lumped", degree=1, total_mass_kg=float(mass.sum()) / d, final=res,
        case_name=case.name, solver="admm")
