"""Newton's iterations at a fixed load on the reference's unknown (``Newton``): residual first,
the tangent only when another correction is needed, a line search against inverted elements
(with indenters, on the total energy, and a Levenberg-Marquardt shift of an indefinite
tangent); and the assembly of the residual and tangent they iterate on. The load stepping
around them is ``ReferenceSolver.solve``. Units: mm, mN."""
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

from .newton_settings import NewtonSettings, Timings

__all__ = ["CONTRACTION", "Newton"]


CONTRACTION = 0.5
"""With indenters, a whole Newton step without the tips' curvature that leaves more than this
fraction of the residual makes the rest of the load step's iterations use the exact tangent
(``NewtonSettings.contact_curvature_below``). Any solve: past ``NewtonSettings.max_iterations``
Newton goes on while each whole step leaves at most this fraction of the residual."""


class Newton:
    """Newton on the unknown ``x`` (a dolfinx Function; corrections in ``du``) of the residual
    form ``R_form`` and its tangent ``K_form`` (``K_halved_form``: without the tips' curvature,
    or None), assembled into ``b`` and ``A``; ``linear`` (``linalg.LinearSolver``) solves for
    the corrections, ``contact`` (``contact.Contact``) is the line search with indenters.

    Extra terms: ``iterate``'s ``extra_terms`` (e.g. the inertia of implicit-Euler dynamics,
    ``dynamics``), an object with add_residual(b, bcs) and add_tangent(A, bcs), added to the
    residual and tangent after assembly, and, for the energy line search, energy() (uJ), which
    Newton adds to the contact's total energy (``Contact.total_energy``).

    Scale: the Dirichlet rows of the residual and of the tangent carry the stiffness E h_min
    (mN/mm, E the material's Constant, h_min the shortest cell edge) instead of 1, so every row
    of the residual is a force (mN) proportional to E and the relative tolerance means the same
    for every E; the absolute one is ``atol`` E h_min^2. ``umap``: the unknown's dof of each
    displacement dof (the corrections' size is measured on the displacement). ``timings``: the
    owner's per-solve counters.

    ``refresh``: called with no argument before every assembly of the residual or the tangent,
    so that coefficients the forms read besides the unknown (the Ogden law's quadrature-point
    Functions, ``ogden_fields``) are those of the unknown's current value
    (``ReferenceSolver.refresh_fields``); None: the forms read the unknown alone."""

    def __init__(self, *, x, du, A, b, R_form, K_form, K_halved_form, E, h_min: float, linear,
                 contact, umap, comm, timings: Timings, refresh=None):
        self.refresh = refresh
        self.x, self.du, self.A, self.b = x, du, A, b
        self.R_form, self.K_form, self.K_halved_form = R_form, K_form, K_halved_form
        self.E, self.h_min, self.linear, self.contact = E, float(h_min), linear, contact
        self.umap, self.comm, self.timings = umap, comm, timings
        # the Dirichlet conditions' values while ``iterate`` runs (its argument); None: unknown
        self.dirichlet_values = None

    def lifting_needed(self) -> bool:
        """Whether the Dirichlet values differ from the unknown's at their dofs (anywhere, on
        any rank), so that lifting the residual by them changes it. Where they agree the lifting
        adds exactly zero and costs an element tangent per cell next to the boundary (on the
        rigid-tip phantoms, whose conditions hold still, about an eighth of a Newton
        iteration). True when the owner did not give the values."""
        if self.dirichlet_values is None:
            return True
        x = self.x.x.array
        moved = any(bool(np.any(g[coll] != x[parent])) for g, parent, coll in self.dirichlet_values)
        return bool(self.comm.allreduce(moved, op=MPI.LOR))

    def bc_stiffness(self) -> float:
        """E h_min (mN/mm): the diagonal of the Dirichlet rows."""
        return float(self.E.value) * self.h_min

    def assemble_residual(self, bcs, extra_terms=None) -> float:
        """b = R(u) with the Dirichlet rows set to E h_min (u - g) (lifting included where the
        values differ from u's, ``lifting_needed``), plus ``extra_terms``' residual (class
        docstring) where given; returns |b| (mN)."""
        t0 = time.perf_counter()
        if self.refresh is not None:
            self.refresh()
        b = self.b
        with b.localForm() as bl:
            bl.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.R_form)
        if self.lifting_needed():
            dolfinx.fem.petsc.apply_lifting(b, [self.K_form], bcs=[bcs], x0=[self.x.vector],
                                            scale=-1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        if extra_terms is not None:
            extra_terms.add_residual(b, bcs)
        dolfinx.fem.petsc.set_bc(b, bcs, self.x.vector, -self.bc_stiffness())
        self.timings.assemble += time.perf_counter() - t0
        return b.norm()

    def assemble_tangent(self, bcs, drop: bool = False, extra_terms=None):
        """The exact tangent, or with indenters and ``drop`` the one without the tips' curvature
        terms (``K_halved_form``, fem_reference.contact), plus ``extra_terms``' tangent (class
        docstring) where given."""
        t0 = time.perf_counter()
        if self.refresh is not None:
            self.refresh()
        self.A.zeroEntries()
        form = self.K_halved_form if drop and self.K_halved_form is not None else self.K_form
        dolfinx.fem.petsc.assemble_matrix(self.A, form, bcs=bcs,
                                          diagonal=self.bc_stiffness())
        self.A.assemble()
        if extra_terms is not None:
            extra_terms.add_tangent(self.A, bcs)
        self.timings.assemble += time.perf_counter() - t0

    def _shift_tangent(self, mu: float):
        """A += mu |diag A| (Levenberg-Marquardt; the Dirichlet rows, whose residual is zero
        after a load step's first correction, keep their corrections at zero)."""
        d = self.A.getDiagonal()
        d.abs()
        d.scale(mu)
        self.A.setDiagonal(d, addv=PETSc.InsertMode.ADD_VALUES)
        self.linear.tangent_changed()

    def _correction(self, s: NewtonSettings, bcs, eta, drop, shift, test, extra_terms):
        """Newton's correction du from the tangent (without the tips' curvature if ``drop``,
        shifted by ``shift`` |diag K| if > 0). ``test``: the energy's slope along du is computed
        and, with ``settings.descent_shift``, a correction that does not descend or whose
        tangent's factorization has negative pivots is solved again: first without the tips'
        curvature, then with the shift growing tenfold from descent_shift, four times at most
        (the last one is taken whatever it gives: the line search still guards the energy).
        Returns (ok, slope (uJ; None untested), drop, shift): the tangent used."""
        while True:
            self.assemble_tangent(bcs, drop, extra_terms)
            if shift > 0:
                self._shift_tangent(shift)
                self.timings.shifts += 1
            t0 = time.perf_counter()
            ok = self.linear.solve(eta)
            self.timings.solve += time.perf_counter() - t0
            if not (ok and test):
                return ok, None, drop, shift
            slope = self.b.dot(self.du.vector)  # b is the residual: the energy's gradient
            if (slope < 0 and not self.linear.negative_pivots) or s.descent_shift == 0 or \
                    shift >= 999.0 * s.descent_shift:
                return True, slope, drop, shift
            if not drop and self.K_halved_form is not None and \
                    s.contact_curvature_after_halving == "drop":
                drop = True
            else:
                shift = max(10.0 * shift, s.descent_shift)

    def iterate(self, s: NewtonSettings, bcs, progress, label, rtol=None, atol_mm=None,
                trace=None, dirichlet_values=None, extra_terms=None,
                residual_line_search: bool = False):
        """Newton iterations at fixed load with the settings ``s``; returns (converged,
        iterations, residual).

        Residual first, tangent only when another correction is needed. A correction that
        inverts an element (non-finite residual) is halved up to ``settings.line_search`` times.
        Past ``settings.max_iterations`` only converging corrections go on (``CONTRACTION``),
        up to twice as many. With the energy line search, a correction after the first that is
        no longer than ``atol_mm`` (of an unshifted tangent) ends the iterations converged,
        before the search.
        ``trace`` (a list) gets the residual norm of every iterate. ``dirichlet_values``: the
        values of ``bcs`` as (value array, dofs of x, dofs of the value array) per condition,
        so that the residual skips a lifting that adds zero (``lifting_needed``); None: always
        lifted. ``extra_terms``: terms added to the residual, the tangent and the line search's
        energy (class docstring); None: none. ``residual_line_search``: without indenters, a
        correction after a load step's first is taken only when it lowers the residual norm
        (halved otherwise, the last halving taken; ``Contact.accepts``); else every finite one
        is taken.
        """
        self.dirichlet_values = dirichlet_values
        try:
            return self._iterate(s, bcs, progress, label, rtol, atol_mm, trace, extra_terms,
                                 residual_line_search)
        finally:
            self.dirichlet_values = None

    @staticmethod
    def _extra_energy(extra_terms) -> float:
        """The energy (uJ) of ``extra_terms`` at the current state; 0 without one."""
        if extra_terms is not None and hasattr(extra_terms, "energy"):
            return extra_terms.energy()
        return 0.0

    def _bend(self, u, start, straight: float, extra_terms) -> float:
        """The trial bent along the tips (``Contact.follow_tips``) when its total energy is
        below ``straight``'s (uJ, that of the straight trial ``u`` holds), else the straight
        one: skin that a retracting tip releases leaves it along the straight line. Returns
        the energy of the trial left in ``u``."""
        straight_u = u.x.array.copy()
        if not self.contact.follow_tips(u.x.array, start, self.umap):
            return straight
        u.x.scatter_forward()
        bent = self.contact.total_energy(self._extra_energy(extra_terms))
        if bent < straight:
            return bent
        u.x.array[:] = straight_u
        return self.contact.total_energy(self._extra_energy(extra_terms))

    def _iterate(self, s, bcs, progress, label, rtol, atol_mm, trace, extra_terms,
                 residual_line_search):
        rtol = s.rtol if rtol is None else rtol
        atol_mm = s.atol_mm if atol_mm is None else atol_mm
        u, du = self.x, self.du
        atol = s.atol * self.bc_stiffness() * self.h_min   # mN
        r0 = rprev = None
        halved = False  # the last correction was halved
        exact = False   # the curvature-free matrix stalled: the exact tangent from here on
        energy = self.contact.energy_search  # the line search tests the energy (indenters)
        shift = 0.0  # Levenberg-Marquardt shift of the tangent (relative to its diagonal)
        floor = 0.5 ** s.line_search  # the shortest step, taken regardless
        converging = False  # the last correction was taken whole and halved the residual
        rnorm = self.assemble_residual(bcs, extra_terms)
        # the first correction is taken whole only when it also moves the Dirichlet values (the
        # start state's energy is then not that of the problem being solved); where they stay,
        # only the tips moved, and the start state's energy, with the tips where they are now,
        # is the one the first trial must lower (a tip that retracts: the tangent, blind to the
        # tip, springs the skin back through it)
        first = 1
        if energy and math.isfinite(rnorm) and not self.lifting_needed():
            first = 0
            self.contact.accepts(rnorm, rnorm, True,
                                 self.contact.total_energy(self._extra_energy(extra_terms)))
        for it in range(1, 2 * s.max_iterations + 1):
            if trace is not None:
                trace.append(rnorm)
            if not math.isfinite(rnorm):
                return False, it, rnorm
            if r0 is None:
                r0 = max(rnorm, 1e-300)
            elif rnorm <= atol or rnorm <= rtol * r0:
                return True, it - 1, rnorm
            if it > s.max_iterations and not converging:
                return False, it - 1, rnorm
            # forcing term of the inexact (Krylov) solves: no more accuracy than Newton can use
            eta = 1e-3 if rprev is None else \
                min(1e-3, max((rnorm / rprev) ** 2, 0.1 * rtol * r0 / rnorm, 1e-12))
            # the tips' curvature is left out of Newton's matrix after a halved correction and
            # while the residual is far above its converged size, until that matrix stalls
            drop = self.K_halved_form is not None and (
                (halved and s.contact_curvature_after_halving == "drop")
                or (not exact and rnorm > s.contact_curvature_below * r0))
            # a first correction that also moves the Dirichlet values is not tested
            ok, slope, drop, shift = self._correction(s, bcs, eta, drop, shift,
                                                      energy and it > first, extra_terms)
            if not ok:
                return False, it, rnorm
            # the largest displacement correction (mm; the pressure's, in kPa, is not compared)
            step = self.comm.allreduce(
                float(np.abs(du.x.array[self.umap]).max(initial=0.0)), op=MPI.MAX)
            if not math.isfinite(step):
                return False, it, float("nan")
            if it == 1 and first == 0 and step <= s.intermediate_atol_mm:
                # a first correction this short carries no skin through a tip, and near
                # round-off the energy cannot judge it: taken whole, as one that moves the
                # Dirichlet values is
                first = 1
            if energy and it > first and step <= atol_mm and shift == 0.0:
                # converged whatever the energy line search would make of a correction this
                # short: at round-off the energy cannot tell the trial from the state, and would
                # cut it forever (a tip that has left the skin at rest: |R| ~ 1e-11, |du| ~
                # 1e-16 mm). The energy search runs on the displacement formulation only, whose
                # correction is all displacement (a mixed one's pressure is not in ``step``); a
                # shifted tangent's correction is damped, no measure of the distance left.
                return True, it, rnorm
            u_old = u.x.array.copy()
            e_old = self.contact.accepted_energy if energy else None
            alpha = 1.0
            while True:
                u.x.array[:] = u_old + alpha * du.x.array
                forced = it == first or alpha <= floor
                # with the energy line search a trial is tested on its energy first: one that
                # the energy refuses needs no residual (an assembly of the residual vector
                # instead of the energy's scalar; most trials where the contact set moves)
                trial = self.contact.total_energy(self._extra_energy(extra_terms)) \
                    if energy and (s.follow_tips or not forced) else None
                if energy and s.follow_tips:
                    trial = self._bend(u, u_old, trial, extra_terms)
                if trial is not None and not forced and not self.contact.lowers(trial):
                    finite = math.isfinite(trial)
                else:
                    rnew = self.assemble_residual(bcs, extra_terms)
                    finite = math.isfinite(rnew)
                    if finite and energy and trial is None:
                        trial = self.contact.total_energy(self._extra_energy(extra_terms))
                    if finite and self.contact.accepts(rnew, rnorm, forced, trial,
                                                       residual=residual_line_search):
                        break
                if alpha <= floor:
                    u.x.array[:] = u_old
                    return False, it, float("nan")
                nxt = 0.5 * alpha
                if s.interpolate and slope is not None and slope < 0 and finite:
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
            converging = alpha == 1.0 and rnew <= CONTRACTION * rnorm
            rprev, rnorm = rnorm, rnew
            halved = alpha < 1.0
            if alpha == 1.0:
                shift = 0.0  # the exact tangent again: Newton's quadratic convergence
                if step <= atol_mm and it > 1:
                    return True, it, rnorm
        return False, 2 * s.max_iterations, rnorm
