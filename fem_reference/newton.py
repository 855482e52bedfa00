"""Newton iterations and load stepping of the reference: residual-first Newton with a line
search against inverted elements (with indenters, on the total energy, and a Levenberg-Marquardt
shift of an indefinite tangent), secant predictor, automatic cut-back; the converged reason is
checked every load step and a failure raises ConvergenceError carrying the last converged state.
Units: mm, mN. Mixed into ReferenceSolver."""
from __future__ import annotations

import math
import sys
import time

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from tissue_reference.meshes.case import Case
from tissue_reference.meshes.errors import CaseError, ConvergenceError
from tissue_reference.meshes.results import SolveResult

from .newton_settings import NewtonSettings, Timings, settings_json

__all__ = ["NewtonMixin", "NewtonSettings", "settings_json"]


CONTRACTION = 0.5
"""With indenters, a whole Newton step without the tips' curvature that leaves more than this
fraction of the residual makes the rest of the load step's iterations use the exact tangent
(``NewtonSettings.contact_curvature_below``)."""


class NewtonMixin:
    """Load stepping and Newton on the solver's unknown (needs the forms, bcs and linear solves).

    Scale: the Dirichlet rows of the residual and of the tangent carry the stiffness E h_min
    (mN/mm) instead of 1, so every row of the residual is a force (mN) proportional to E and the
    relative tolerance means the same for every E; the absolute one is ``atol`` E h_min^2."""

    # terms added to the residual and tangent after assembly (e.g. the inertia of implicit-Euler
    # dynamics, ``dynamics``): an object with add_residual(b, bcs) and add_tangent(A, bcs)
    extra_terms = None

    def _bc_stiffness(self) -> float:
        """E h_min (mN/mm): the diagonal of the Dirichlet rows."""
        return float(self.E.value) * float(self.dm.h_min)

    def assemble_residual(self, bcs) -> float:
        """b = R(u) with the Dirichlet rows set to E h_min (u - g) (lifting included); returns
        |b| (mN)."""
        t0 = time.perf_counter()
        b = self.b
        with b.localForm() as bl:
            bl.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.R_form)
        dolfinx.fem.petsc.apply_lifting(b, [self.K_form], bcs=[bcs], x0=[self.x.vector], scale=-1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        if self.extra_terms is not None:
            self.extra_terms.add_residual(b, bcs)
        dolfinx.fem.petsc.set_bc(b, bcs, self.x.vector, -self._bc_stiffness())
        self.timings.assemble += time.perf_counter() - t0
        return b.norm()

    def assemble_tangent(self, bcs, drop: bool = False):
        """The exact tangent, or with indenters and ``drop`` the one without the tips' curvature
        terms (``K_halved_form``, fem_reference.contact)."""
        t0 = time.perf_counter()
        self.A.zeroEntries()
        form = self.K_halved_form if drop and self.K_halved_form is not None else self.K_form
        dolfinx.fem.petsc.assemble_matrix(self.A, form, bcs=bcs,
                                          diagonal=self._bc_stiffness())
        self.A.assemble()
        if self.extra_terms is not None:
            self.extra_terms.add_tangent(self.A, bcs)
        self.timings.assemble += time.perf_counter() - t0


    def _shift_tangent(self, mu: float):
        """A += mu |diag A| (Levenberg-Marquardt; the Dirichlet rows, whose residual is zero
        after a load step's first correction, keep their corrections at zero)."""
        d = self.A.getDiagonal()
        d.abs()
        d.scale(mu)
        self.A.setDiagonal(d, addv=PETSc.InsertMode.ADD_VALUES)
        self.refactor = True

    def _correction(self, bcs, eta, drop, shift, test):
        """Newton's correction du from the tangent (without the tips' curvature if ``drop``,
        shifted by ``shift`` |diag K| if > 0). ``test``: the energy's slope along du is computed
        and, with ``settings.descent_shift``, a correction that does not descend or whose
        tangent's factorization has negative pivots is solved again: first without the tips'
        curvature, then with the shift growing tenfold from descent_shift, four times at most
        (the last one is taken whatever it gives: the line search still guards the energy).
        Returns (ok, slope (uJ; None untested), drop, shift): the tangent used."""
        s = self.settings
        while True:
            self.assemble_tangent(bcs, drop)
            if shift > 0:
                self._shift_tangent(shift)
                self.timings.shifts += 1
            t0 = time.perf_counter()
            ok = self.linear_solve(eta)
            self.timings.solve += time.perf_counter() - t0
            if not (ok and test):
                return ok, None, drop, shift
            slope = self.b.dot(self.du.vector)  # b is the residual: the energy's gradient
            if (slope < 0 and not self.negative_pivots) or s.descent_shift == 0 or \
                    shift >= 999.0 * s.descent_shift:
                return True, slope, drop, shift
            if not drop and self.K_halved_form is not None and \
                    s.contact_curvature_after_halving == "drop":
                drop = True
            else:
                shift = max(10.0 * shift, s.descent_shift)

    def _newton(self, bcs, progress, label, rtol=None, atol_mm=None, trace=None):
        """Newton iterations at fixed load; returns (converged, iterations, residual).

        Residual first, tangent only when another correction is needed. A correction that
        inverts an element (non-finite residual) is halved up to ``settings.line_search`` times.
        ``trace`` (a list) gets the residual norm of every iterate.
        """
        s = self.settings
        rtol = s.rtol if rtol is None else rtol
        atol_mm = s.atol_mm if atol_mm is None else atol_mm
        u, du = self.x, self.du
        atol = s.atol * self._bc_stiffness() * float(self.dm.h_min)   # mN
        r0 = rprev = None
        halved = False  # the last correction was halved
        exact = False   # the curvature-free matrix stalled: the exact tangent from here on
        energy = self.contact.energy_search  # the line search tests the energy (indenters)
        shift = 0.0  # Levenberg-Marquardt shift of the tangent (relative to its diagonal)
        floor = 0.5 ** s.line_search  # the shortest step, taken regardless
        rnorm = self.assemble_residual(bcs)
        for it in range(1, s.max_iterations + 1):
            if trace is not None:
                trace.append(rnorm)
            if not math.isfinite(rnorm):
                return False, it, rnorm
            if r0 is None:
                r0 = max(rnorm, 1e-300)
            elif rnorm <= atol or rnorm <= rtol * r0:
                return True, it - 1, rnorm
            # forcing term of the inexact (Krylov) solves: no more accuracy than Newton can use
            eta = 1e-3 if rprev is None else \
                min(1e-3, max((rnorm / rprev) ** 2, 0.1 * rtol * r0 / rnorm, 1e-12))
            # the tips' curvature is left out of Newton's matrix after a halved correction and
            # while the residual is far above its converged size, until that matrix stalls
            drop = self.K_halved_form is not None and (
                (halved and s.contact_curvature_after_halving == "drop")
                or (not exact and rnorm > s.contact_curvature_below * r0))
            # the first correction of a load step also moves the Dirichlet values: not tested
            ok, slope, drop, shift = self._correction(bcs, eta, drop, shift, energy and it > 1)
            if not ok:
                return False, it, rnorm
            # the largest displacement correction (mm; the pressure's, in kPa, is not compared)
            step = self.comm.allreduce(
                float(np.abs(du.x.array[self._umap]).max(initial=0.0)), op=MPI.MAX)
            if not math.isfinite(step):
                return False, it, float("nan")
            u_old = u.x.array.copy()
            e_old = self.contact.accepted_energy if energy else None
            alpha = 1.0
            while True:
                u.x.array[:] = u_old + alpha * du.x.array
                rnew = self.assemble_residual(bcs)
                if math.isfinite(rnew) and self.contact.accepts(
                        rnew, rnorm, it == 1 or alpha <= floor):
                    break
                if alpha <= floor:
                    u.x.array[:] = u_old
                    return False, it, float("nan")
                nxt = 0.5 * alpha
                if s.interpolate and slope is not None and slope < 0 and math.isfinite(rnew):
                    # minimizer of the quadratic through E(0), E'(0) and E(alpha)
                    curv = self.contact.trial_energy - e_old - slope * alpha
                    if curv > 0:
                        nxt = min(0.5 * alpha, max(0.1 * alpha, -slope * alpha ** 2 / (2 * curv)))
                alpha = max(nxt, floor)
            if progress and self.comm.rank == 0:
                why = "energy or inverted elements" if self.contact.indenters else \
                    "inverted elements"
                ls = "" if alpha == 1.0 else f"  (step x{alpha:.3g}: {why})"
                lm = f"  (tangent shifted {shift:g})" if shift > 0 else ""
                print(f"  {label} newton {it:2d}  |R| {rnorm:.3e}  |du|_max {step:.3e} mm{ls}{lm}",
                      file=sys.stderr, flush=True)
            if drop and alpha == 1.0 and it > 1 and rnew > CONTRACTION * rnorm:
                exact = True   # a whole step that did not halve the residual: the tips'
                # curvature carries the tangent here (a contact pressed hard)
            rprev, rnorm = rnorm, rnew
            halved = alpha < 1.0
            if alpha == 1.0:
                shift = 0.0  # the exact tangent again: Newton's quadratic convergence
                if step <= atol_mm and it > 1:
                    return True, it, rnorm
        return False, s.max_iterations, rnorm

    def _max_prescribed(self, case, override):
        m = np.abs(case.constraints.values).max(initial=0.0)
        for b in case.boundaries:
            if b.type == "sliding":
                m = max(m, abs(float(b.value or 0.0)))
        if override is not None:
            m = max(m, np.abs(np.asarray(override[1], float)).max(initial=0.0))
        return m

    def solve(self, pushes=None, *, case: Case | None = None, initial=None, dirichlet_override=None,
              progress: bool = False, cases_first=None) -> SolveResult:
        """Solve ``case`` (default: the one given at construction) with ``pushes`` applied.

        pushes: actuator name -> push (mm) along its direction.
        initial: warm start: (n_vertices, gdim) in the Case numbering (at degree 2 the edge
            nodes start at the mean of their end vertices), the full (n_nodes, gdim) degree-2
            nodal state in Tangent node order, or a previous SolveResult of a reference solve on
            this mesh (degree 2: its full nodal state); the load path starts from the case's
            prescribed values at fraction 0 scaled from there.
        dirichlet_override: (dofs, values): extra per-vertex prescriptions (node-major Case dofs,
            mm at full load), degree 1.
        Raises ConvergenceError (with ``last_converged`` SolveResult and the load fraction reached)
        when a load step still fails after the cut-backs.
        """
        t_start = time.perf_counter()
        self.timings = Timings(setup=self.timings.setup)  # per-solve counters
        self._fresh_linear_state()   # nothing of an earlier solve steers this one
        case = (case or self.case).with_pushes(pushes or {})
        if case.mesh is not self.case.mesh:
            raise CaseError("ReferenceSolver.solve: the case mesh differs from the solver's mesh")
        if (case.material.model, case.material.volumetric) != \
                (self.case.material.model, self.case.material.volumetric):
            raise CaseError(f"ReferenceSolver.solve: the case's material law "
                            f"({case.material.model}, volumetric {case.material.volumetric!r}) "
                            f"differs from the solver's ({self.case.material.model}, volumetric "
                            f"{self.case.material.volumetric!r}): build a solver for it")
        self.E.value = case.material.E
        self.nu.value = case.material.nu
        self.inv_kappa.value = 3.0 * (1.0 - 2.0 * case.material.nu) / case.material.E
        s = self.settings
        warm = initial is not None
        if warm:
            self.set_state(initial)
        else:
            self.x.x.array[:] = 0.0
        # Dirichlet data at full load; each load step sets g = start + lam (full - start), where
        # start is the state's own boundary values (0 when cold), so a warm start ramps from
        # where it is to the new prescriptions.
        entries = self.dirichlet_bcs(case, 1.0, dirichlet_override)
        bcs = [e[0] for e in entries]
        ramps = []
        span = 0.0
        for _, gfun, parent, coll in entries:
            garr = gfun.x.array
            full = garr.copy()
            start = np.zeros_like(full)
            if warm:
                start[coll] = self.x.x.array[parent]
            ramps.append((garr, start, full))
            span = max(span, np.abs(full[coll] - start[coll]).max(initial=0.0))
        span = max(span, self.contact.ramps(case, ramps, initial))  # indenters' tips
        span = self.comm.allreduce(span, op=MPI.MAX)
        inc = 1.0 if span <= s.max_step_mm else s.max_step_mm / span
        lam = 0.0
        steps = iters = 0
        last_good = self.x.x.array.copy()
        residual = 0.0
        # per load step reached; and per Newton iterate (failed steps too) its residual norm
        # and the load fraction it was tried at
        history = {"load_fraction": [], "newton_iterations": [], "residual": [],
                   "iterate_residual": [], "iterate_load": []}
        prev_good, prev_lam = None, 0.0
        predict = s.predictor == "secant"
        while lam < 1.0 - 1e-14:
            trial = min(1.0, lam + inc)
            for garr, start, full in ramps:
                garr[:] = start + trial * (full - start)
            self.load.value = 1.0 if warm else trial
            if predict and prev_good is not None and lam > prev_lam:
                # linear extrapolation of the load path (secant predictor)
                self.x.x.array[:] += (trial - lam) / (lam - prev_lam) * (last_good - prev_good)
                self.x.x.scatter_forward()
            final = trial >= 1.0 - 1e-14
            tol = {} if final else {"rtol": s.intermediate_rtol, "atol_mm": s.intermediate_atol_mm}
            trace = history["iterate_residual"]
            ok, it, res = self._newton(bcs, progress, f"load {trial:6.3f}", trace=trace, **tol)
            iters += it
            if not ok and predict and prev_good is not None:
                # retry the same step from the last converged state, without the predictor
                self.x.x.array[:] = last_good
                self.x.x.scatter_forward()
                ok, it, res = self._newton(bcs, progress, f"load {trial:6.3f}", trace=trace,
                                           **tol)
                iters += it
            history["iterate_load"] += [trial] * (len(trace) - len(history["iterate_load"]))
            if ok:
                prev_good, prev_lam = last_good.copy(), lam
                lam = trial
                steps += 1
                residual = res
                last_good[:] = self.x.x.array
                history["load_fraction"].append(lam)
                history["newton_iterations"].append(it)
                history["residual"].append(res)
                if progress and self.comm.rank == 0:
                    print(f"tissue fem: load fraction {lam:.4f} converged in {it} Newton "
                          f"iterations (|R| {res:.2e})", file=sys.stderr, flush=True)
                if it <= 5:
                    inc *= s.grow
            else:
                self.x.x.array[:] = last_good
                self.x.x.scatter_forward()
                inc /= 2.0
                if progress and self.comm.rank == 0:
                    print(f"tissue fem: load fraction {trial:.4f} failed, cutting the step to "
                          f"{inc:.4f}", file=sys.stderr, flush=True)
                if inc < s.min_fraction:
                    # the last converged state with its own prescriptions: the Dirichlet values
                    # and the indenters' tips back where that state was solved
                    for garr, start, full in ramps:
                        garr[:] = start + lam * (full - start)
                    self.load.value = 1.0 if warm else lam
                    wall = time.perf_counter() - t_start
                    last = self._result(case, False, iters, residual, wall, steps, history, lam)
                    raise ConvergenceError(
                        f"{case.source or case.name}: Newton did not converge beyond load fraction "
                        f"{lam:.4f} (tried {trial:.4f}) after cut-backs down to {inc * 2:.2e}"
                        f"{self.contact.failure_hint()}",
                        load_fraction=lam, last_converged=last)
        wall = time.perf_counter() - t_start
        return self._result(case, True, iters, residual, wall, max(steps, 1), history, 1.0)

    # ------------------------------------------------------------------ state I/O
