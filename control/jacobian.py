"""Control Jacobians of seed 000 (section III-A) from a tangent stiffness K.

Two sensitivities of the internal targets' displacement (mm) to the actuators:

* ``dirichlet_jacobian`` -- the actuator is a rigid patch (its region's dofs prescribed) pushed
  along its unit direction d_i. Partition the dofs into free (f) and prescribed (p: the Case's
  Dirichlet dofs plus every actuator region's dofs), then

      K_ff du_f = -K_fp du_p,   du_p = d_i on actuator i's dofs, 0 elsewhere,
      dx_target = P du,

  one column per actuator, mm of target per mm of push. This is the exact derivative of the
  quasi-static solve ``solve(case.with_pushes({A1: s1, ..., An: sn}))`` with respect to s_i when K
  is the consistent tangent at that solution: every actuator is held at its push (a push of 0 holds
  its patch in place), exactly as :func:`fd_jacobian` perturbs it.

* ``force_jacobian`` -- seed eq. 19 with point (or patch) forces as inputs:
  J_s = J_m^T K^-1 J_c (J_c^T K^-1 J_c)^-1 with K restricted to the free dofs of the Case (actuator
  regions free), J_c the unit force along d_i at actuator i's control point(s), J_m^T = P.

* ``admm_indenter_jacobian`` -- the actuator is a rigid tip of the ADMM model (frictionless
  contact, ``solvers.admm.contact``): at the model's converged state u the free residual
  r_f(u, s) = Z^T (f_int(u) + dPi_c/du(u, o(s)) - f_ext) vanishes, the tip's end o moving by
  d_t per mm of push s_t. Then

      K_r X_t = -Z^T dr/ds_t,   dr/ds_t = -S^T (H_p d_t) over tip t's contact points,
      dx_target = P Z X_t,

  with K_r the reduced exact tangent (elements and the contact's Hessian, curvature included:
  the state's active contact set), H_p a contact point's penalty Hessian in its position.

K is node-major (dof = 3 * node + c), full size (constrained dofs included), in the Case's vertex
numbering; degree-2 tangents carry extra (edge) nodes after the vertices: pass ``P`` (target
interpolation on the whole dof vector) and ``region_nodes`` (node ids of a region, extra nodes
included) for them (``control.dof_maps``: ``p2_interpolation``, ``p2_region_nodes``).

Rows of every Jacobian: T1.x, T1.y, T1.z, T2.x, ...; columns: actuators in the Case's order.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.solvers.admm import prepare

from .dof_maps import probe_matrix

__all__ = [
    "ControlJacobian",
    "admm_indenter_jacobian",
    "dirichlet_jacobian",
    "fd_jacobian",
    "force_jacobian",
    "full_pushes",
    "max_rel_error",
    "target_rows",
]


@dataclass(frozen=True)
class ControlJacobian:
    """J (3 * n_targets, n_actuators), mm per mm (Dirichlet) or mm per mN (forces).

    rows: names "T1.x", "T1.y", ...; ``block(target)`` is the (gdim, n_actuators) block of one
    target.
    """

    J: np.ndarray
    actuators: tuple
    targets: tuple
    kind: str = "dirichlet"
    gdim: int = 3
    wall_time_s: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def rows(self) -> list[str]:
        return target_rows(self.targets, self.gdim)

    def block(self, target: str) -> np.ndarray:
        if target not in self.targets:
            raise CaseError(f"target {target!r} is not in this Jacobian; targets: "
                            f"{list(self.targets)}")
        i = self.targets.index(target)
        return self.J[self.gdim * i: self.gdim * (i + 1)]


def target_rows(targets, gdim=3) -> list[str]:
    """The row names of a Jacobian: per target its components, "T1.x", "T1.y", ...

    Parameters
    ----------
    targets : sequence of str
        Target (probe) names.
    gdim : int
        Components per target (2 or 3).

    Returns
    -------
    list of str
        gdim * len(targets) names.
    """
    return [f"{t}.{'xyz'[c]}" for t in targets for c in range(gdim)]


def _names(case, actuators, targets):
    acts = tuple(a.name for a in case.actuators) if actuators is None else tuple(actuators)
    tg = tuple(p.name for p in case.probes) if targets is None else tuple(targets)
    for a in acts:
        case.actuator(a)  # raises CaseError naming the missing actuator
    for t in tg:
        case.probe(t)
    if not acts:
        raise CaseError(f"{case.source or case.name}: the Case has no actuators")
    if not tg:
        raise CaseError(f"{case.source or case.name}: the Case has no targets (probes)")
    return acts, tg


def _check_K(K, case, P, internal=0):
    """K as CSR and P padded to K's size. ``internal``: trailing dofs of K that are not
    displacements (the pressure of the mixed formulation): free and unforced, so every solve with
    K condenses them out exactly."""
    d = case.mesh.gdim
    if not sp.issparse(K):
        K = sp.csr_matrix(np.asarray(K, float))
    K = K.tocsr()
    n = K.shape[0]
    nu = n - int(internal)
    if K.shape[0] != K.shape[1] or internal < 0 or nu % d or nu < d * case.mesh.n_vertices:
        raise CaseError(f"tangent K of shape {K.shape} does not fit the Case: it must be square, "
                        f"node-major with at least {d}*{case.mesh.n_vertices} displacement rows "
                        f"(then {internal} internal dofs)")
    if nu > d * case.mesh.n_vertices and P is None:
        raise CaseError(f"tangent K has {nu // d} nodes but the Case mesh {case.mesh.n_vertices} "
                        f"vertices (degree 2?): pass P, the target interpolation on all {nu} dofs, "
                        f"and region_nodes")
    if P is not None:
        P = sp.csr_matrix(P)
        if P.shape[1] == nu and internal:
            P = sp.hstack([P, sp.csr_matrix((P.shape[0], internal))]).tocsr()
        if P.shape[1] != n:
            raise CaseError(f"interpolation P of shape {P.shape} does not match K's {nu} "
                            f"displacement dofs")
    return K, P


def _region_dofs(case, region, d, region_nodes):
    nodes = case.mesh.region_vertices(region) if region_nodes is None else \
        np.asarray(region_nodes(region), np.int64)
    return nodes, (d * nodes[:, None] + np.arange(d)).ravel()


def dirichlet_jacobian(case, K, *, actuators=None, targets=None, P=None,
                       region_nodes=None, internal_dofs=0) -> ControlJacobian:
    """Exact sensitivity (mm/mm) of target displacements to rigid pushes of actuator patches.

    case: the Case (its Dirichlet dofs stay prescribed; sliding on oblique planes is refused).
    K: tangent stiffness at the state (CSR, mN/mm, node-major, constrained dofs included).
    P: optional (gdim * n_targets, n_dofs) interpolation of the targets (default: P1 probes).
    region_nodes: optional callable region -> node ids of K (degree 2: vertices and edge nodes);
        default: the Case mesh's region vertices. It is used for the Case's boundary regions too.
    internal_dofs: trailing dofs of K that are not displacements (``Tangent.internal_dofs``: the
        mixed formulation's pressure); they stay free, which condenses them out exactly.

    Parameters
    ----------
    case : Case
        The Case at the state of K.
    K : sparse matrix
        Tangent stiffness (mN/mm, CSR, node-major), constrained dofs included.
    actuators : sequence of str or None
        Actuator names, one column each; None: every actuator of the case.
    targets : sequence of str or None
        Target (probe) names, gdim rows each; None: every probe.
    P : sparse matrix or None
        (gdim * n_targets, n_dofs) interpolation of the targets; None: P1 at the probes.
    region_nodes : callable or None
        region -> node ids of K; None: the Case mesh's region vertices.
    internal_dofs : int
        Trailing dofs of K that are not displacements (the mixed formulation's pressure).

    Returns
    -------
    ControlJacobian
        J (mm/mm), (gdim * n_targets, n_actuators).

    Raises
    ------
    CaseError
        For sliding on oblique planes, unknown actuators or targets, or a K of the wrong size.
    """
    t0 = time.perf_counter()
    acts, tg = _names(case, actuators, targets)
    K, P = _check_K(K, case, P, internal_dofs)
    d = case.mesh.gdim
    n = K.shape[0]
    c = case.constraints
    if c.sliding:
        raise CaseError(f"{case.source or case.name}: oblique sliding conditions are not supported "
                        f"by dirichlet_jacobian")
    fixed = np.zeros(n, bool)
    if region_nodes is None:
        fixed[c.dofs] = True
    else:
        act_regions = {case.actuator(a).region for a in acts}
        for b in case.boundaries:
            if b.type == "traction" or b.region in act_regions:
                continue
            if b.type == "displacement" and b.components is not None:
                nodes, _ = _region_dofs(case, b.region, d, region_nodes)
                for comp in b.components:
                    fixed[d * nodes + comp] = True
            elif b.type == "sliding":
                nodes, _ = _region_dofs(case, b.region, d, region_nodes)
                k = int(np.argmax(np.abs(np.asarray(b.normal, float))))
                fixed[d * nodes + k] = True
            else:
                fixed[_region_dofs(case, b.region, d, region_nodes)[1]] = True
    dUp = np.zeros((n, len(acts)))
    for j, a in enumerate(acts):
        act = case.actuator(a)
        nodes, dofs = _region_dofs(case, act.region, d, region_nodes)
        fixed[dofs] = True
        dUp[dofs, j] = np.tile(np.asarray(act.direction), len(nodes))
    free = np.flatnonzero(~fixed)
    pres = np.flatnonzero(fixed)
    Kff = K[free][:, free].tocsc()
    Kfp = K[free][:, pres]
    rhs = -(Kfp @ dUp[pres])
    lu = spla.splu(Kff)
    du = dUp.copy()
    du[free] = lu.solve(np.ascontiguousarray(rhs))
    Pm = probe_matrix(case, tg, n_dofs=n) if P is None else sp.csr_matrix(P)
    J = np.asarray(Pm @ du)
    return ControlJacobian(J, acts, tg, "dirichlet", d, time.perf_counter() - t0,
                           {"n_free": len(free)})


def admm_indenter_jacobian(case, u, *, actuators=None, targets=None,
                           contact: dict | None = None) -> ControlJacobian:
    """Exact sensitivity (mm/mm) of target displacements to the pushes of the ADMM model's
    rigid tips (module docstring) at its converged state u (mm, (n, gdim)) of ``case`` (the
    case with the pushes of that state; its other actuators held). actuators: indenter names
    (default: every indenter), one column each; contact: the ADMM solve's contact options
    (``solvers.admm.prepare``; default the case's).

    Parameters
    ----------
    case : Case
        The case with the pushes of the state.
    u : ndarray
        The ADMM model's converged state (mm, (n, gdim)).
    actuators : sequence of str or None
        Indenter names, one column each; None: every indenter.
    targets : sequence of str or None
        Target (probe) names; None: every probe.
    contact : dict or None
        The ADMM solve's contact options; None: the case's.

    Returns
    -------
    ControlJacobian
        J (mm/mm), (gdim * n_targets, n_actuators).
    """
    t0 = time.perf_counter()
    tips = [a.name for a in case.indenters()]
    acts, tg = _names(case, tips if actuators is None else actuators, targets)
    missing = [a for a in acts if a not in tips]
    if missing:
        raise CaseError(f"{missing} are not indenters of {case.source or case.name}; "
                        f"indenters: {tips}")
    ops = prepare(case, contact=contact)
    cset = ops.contact
    o = cset.origins(cset.pushes_of(case))
    uu = np.asarray(u, float).reshape(-1)
    Kr, _ = ops.reduced_tangent(uu, extra=cset.hessian(uu, o))
    order = [t.name for t in cset.tips]
    C = cset.push_derivative(uu, o)[:, [order.index(a) for a in acts]]
    try:
        X = -spla.splu(Kr.tocsc()).solve(np.ascontiguousarray(ops.red.ZT @ C))
    except RuntimeError as exc:
        raise ConvergenceError(f"the ADMM model's tangent is singular: {exc}") from None
    J = np.asarray(probe_matrix(case, tg, n_dofs=ops.N) @ (ops.red.Z @ X))
    return ControlJacobian(J, acts, tg, "indenter", case.mesh.gdim, time.perf_counter() - t0,
                           {"n_free": ops.nq})


def force_jacobian(case, K, *, actuators=None, targets=None, P=None, control="point",
                   region_nodes=None, internal_dofs=0) -> ControlJacobian:
    """Seed 000 eq. 19: J_s = J_m^T K^-1 J_c (J_c^T K^-1 J_c)^-1 (mm of target per mm of control
    point displacement along d_i), K restricted to the Case's free dofs (actuator regions free).

    control: "point" -- the force acts at the region vertex nearest to the region's centroid;
             "patch" -- the unit force is spread evenly over the region's nodes (x_c = mean
             displacement of the patch along d_i).
    Also returned in ``extra``: "G" = J_m^T K^-1 J_c (mm per mN) and "C" = J_c^T K^-1 J_c.
    internal_dofs: as for :func:`dirichlet_jacobian`.

    Parameters
    ----------
    case : Case
        The Case at the state of K (actuator regions free).
    K : sparse matrix
        Tangent stiffness (mN/mm, CSR, node-major), constrained dofs included.
    actuators : sequence of str or None
        Actuator names, one column each; None: every actuator of the case.
    targets : sequence of str or None
        Target (probe) names, gdim rows each; None: every probe.
    P : sparse matrix or None
        (gdim * n_targets, n_dofs) interpolation of the targets; None: P1 at the probes.
    control : str
        "point" or "patch" (as above).
    region_nodes : callable or None
        region -> node ids of K; None: the Case mesh's region vertices.
    internal_dofs : int
        Trailing dofs of K that are not displacements.

    Returns
    -------
    ControlJacobian
        J_s (mm/mm); extra["G"] (mm/mN) and extra["C"] (mm/mN).
    """
    t0 = time.perf_counter()
    if control not in ("point", "patch"):
        raise CaseError(f"control must be 'point' or 'patch', got {control!r}")
    acts, tg = _names(case, actuators, targets)
    K, P = _check_K(K, case, P, internal_dofs)
    d = case.mesh.gdim
    n = K.shape[0]
    fixed = np.zeros(n, bool)
    fixed[case.constraints.dofs] = True
    for a in acts:
        r = case.actuator(a).region
        if np.any(fixed[_region_dofs(case, r, d, None)[1]]):
            raise CaseError(f"actuator {a!r}: region {r!r} carries a Dirichlet condition in this "
                            f"Case; force inputs need it free (use the Case without pushes)")
    Jc = np.zeros((n, len(acts)))
    for j, a in enumerate(acts):
        act = case.actuator(a)
        nodes, _ = _region_dofs(case, act.region, d, region_nodes)
        if control == "point":
            X = case.mesh.points
            verts = case.mesh.region_vertices(act.region)
            v = verts[np.argmin(np.linalg.norm(X[verts] - X[verts].mean(0), axis=1))]
            Jc[d * v: d * v + d, j] = act.direction
        else:
            for v in nodes:
                Jc[d * v: d * v + d, j] = np.asarray(act.direction) / len(nodes)
    free = np.flatnonzero(~fixed)
    lu = spla.splu(K[free][:, free].tocsc())
    X = np.zeros((n, len(acts)))
    X[free] = lu.solve(np.ascontiguousarray(Jc[free]))   # K^-1 J_c
    Pm = probe_matrix(case, tg, n_dofs=n) if P is None else sp.csr_matrix(P)
    G = np.asarray(Pm @ X)
    C = Jc.T @ X
    J = G @ np.linalg.inv(C)
    return ControlJacobian(J, acts, tg, "force-" + control, d, time.perf_counter() - t0,
                           {"G": G, "C": C})


def full_pushes(case, pushes=None) -> dict:
    """Every actuator of the Case with its push (mm); missing ones are held at 0.

    Parameters
    ----------
    case : Case
        The Case.
    pushes : dict or None
        Actuator name -> push (mm); None: none.

    Returns
    -------
    dict
        Every actuator's name -> push (mm).
    """
    pushes = dict(pushes or {})
    for a in pushes:
        case.actuator(a)
    return {a.name: float(pushes.get(a.name, 0.0)) for a in case.actuators}


def fd_jacobian(plant, case, state_pushes=None, *, h=0.05, actuators=None, targets=None,
                initial=None) -> ControlJacobian:
    """Central finite differences (mm/mm) of the nonlinear solve with respect to each push:
    (x(s + h e_i) - x(s - h e_i)) / (2 h), every actuator held (pushes of 0 included).

    plant(case, pushes, initial_u) -> SolveResult with ``probes`` (name -> displacement, mm) and
    ``u``.
    h in mm. Raises ConvergenceError when a solve does not converge.

    Parameters
    ----------
    plant : callable
        plant(case, pushes, initial_u) -> SolveResult.
    case : Case
        The Case.
    state_pushes : dict or None
        Actuator name -> push (mm) of the state s; None: rest.
    h : float
        Finite-difference step (mm).
    actuators : sequence of str or None
        Actuator names, one column each; None: every actuator of the case.
    targets : sequence of str or None
        Target (probe) names, gdim rows each; None: every probe.
    initial : ndarray or None
        Warm start (mm, (n, gdim)) of the solves; None: rest.

    Returns
    -------
    ControlJacobian
        J (mm/mm).

    Raises
    ------
    ConvergenceError
        When a solve does not converge.
    """
    t0 = time.perf_counter()
    if not (np.isfinite(h) and h > 0):
        raise CaseError(f"finite-difference step h must be > 0 mm, got h={h!r}")
    acts, tg = _names(case, actuators, targets)
    base = full_pushes(case, state_pushes)
    d = case.mesh.gdim
    J = np.zeros((d * len(tg), len(acts)))
    for j, a in enumerate(acts):
        vals = []
        for s in (+h, -h):
            p = dict(base)
            p[a] += s
            r = plant(case, p, initial)
            if not r.converged:
                raise ConvergenceError(f"fd_jacobian: solve with pushes {p} did not converge "
                                       f"(residual {r.residual:g})")
            vals.append(np.concatenate([np.asarray(r.probes[t], float) for t in tg]))
        J[:, j] = (vals[0] - vals[1]) / (2 * h)
    return ControlJacobian(J, acts, tg, "fd", d, time.perf_counter() - t0, {"h": h})


def max_rel_error(J, J_ref) -> float:
    """max |J - J_ref| / max |J_ref| (the matrix-relative error, dimensionless).

    Parameters
    ----------
    J, J_ref : ControlJacobian or ndarray
        The Jacobian and the one it is compared with (same shape).

    Returns
    -------
    float
        The matrix-relative error.
    """
    J, J_ref = np.asarray(J, float), np.asarray(J_ref, float)
    scale = np.abs(J_ref).max()
    return float(np.abs(J - J_ref).max() / scale) if scale > 0 else float(np.abs(J).max())
