"""ADMM fast solver of seed 000 (eqs. 5-10; Overby et al. 2017, "ADMM ⊇ Projective Dynamics").

Problem (seed eq. 5/6), P1 simplices, displacement u (mm) node-major (dof = gdim*v + c):

    min_u  1/(2 dt^2) ||u - u_tilde||_M^2 + sum_e V_e psi(I + H_e) - f_ext . u,   H_e = D_e u = grad u

(the mass term only for implicit-Euler dynamics; quasi-static equilibrium drops it). ADMM splits
z_e ~ H_e with the constraint W (D u - z) = 0, W_e = w_e I, and iterates (scaled dual lam):

    x-step (eq. 7):  (M/dt^2 + D^T W^2 D) u = M u_tilde/dt^2 + D^T W^2 (z - lam) + f_ext
    z-step (eq. 8/10, every element at once):
                     z_e = argmin_z V_e psi(I + z) + w_e^2/2 |z - (D_e u + lam_e)|^2
    dual (eq. 9):    lam_e += D_e u - z_e

Weights: w_e^2 = rho * V_e (V_e the reference volume, mm^3; rho in kPa), i.e. one penalty
stiffness per unit volume for the whole mesh. D^T W^2 D is then rho times the P1 vector
Laplacian, set up once per Case and reused by every iteration, every load value and every warm
start. Default rho = kappa + 4 mu / 3 = lambda + 2 mu (the P-wave modulus) for both materials;
overridable (``rho=``).

Material (seed eq. 14, ``case.material``): psi = mu/2 (J^(-2/3) I1 - 3) + kappa/2 (J - 1)^2,
or linear elasticity psi = mu eps:eps + lambda/2 tr(eps)^2. 2D meshes are plane strain (F33 = 1).

z-step: linear elasticity in closed form. Neo-Hookean: one safeguarded model-Newton step per
ADMM iteration for every element, warm-started from the previous z (``kernel_array.ZStep``); at
a fixed point the z-step gradient vanishes, so the fixed point is exact whatever the model. The
element work of an iteration (gather of D u, z-step, dual update, residuals, scatter of the next
x-step data) runs in one compiled pass (``kernel_c``, built on first use) or on numpy/CuPy arrays
(``kernel_array``, the same arithmetic). Elements and vertices are ordered internally by reverse
Cuthill-McKee rank (locality on large meshes; element numbers in error messages are the mesh's).
One iteration at ~1.8k tets takes about 0.17-0.32 ms on the shared 2-core development machine,
depending on its load (``bench/bench_admm.py``).

Devices (``solve(..., device=)``, ``backends``): "cpu" (default) runs the compiled element pass
and the x-step by SuperLU (AMG-preconditioned CG on large meshes, ``operators``); "gpu" runs the
element pass and a Jacobi-preconditioned CG x-step on a GPU with CuPy, float64 (optional extra
``gpu``; ``GpuUnavailableError`` without CuPy or a GPU). Setup, lifts, the polish and the final
checks stay on the host either way.

Stopping rule and rho adaptation: ``loop``. ADMM converges linearly, so by default a "Newton
polish" follows (``polish``): Newton steps on the same P1 energy with this package's exact
tangent until the largest Newton step is below ``polish_tol_mm``. With the polish, ADMM only has
to bring each load step near Newton's basin: it hands over at ``handoff_mm`` (0.01 mm) or after
``max_iter`` iterations (default 20 with the polish, 20000 without); on the phantom with all four
actuators pushed 15 mm (1782 tets) this cut the solve from 6486 ADMM iterations + 10 Newton
(about 12.6 s in ``make demo``) to 86 ADMM + 14 Newton iterations, same answer (to 1e-11 mm).
Both iteration counts are reported (``extra["admm_iterations"]``, ``extra["newton_iterations"]``);
``history["admm_clock_s"]`` holds the wall-clock time (s, from the start of the solve) at the end
of every ADMM iteration.

Anderson acceleration (``solve(..., anderson=m)``, ``loop.Anderson``): the ADMM iteration as
a fixed-point map of its element and contact variables, extrapolated from its last m iterates
with a residual and no-inversion safeguard (Zhang et al. 2019); plain ADMM (``anderson=0``, the
seed's) stays the default. Measured (``bench/bench_admm_accel.py``, phantom, all four pushed 4
mm, tol 1e-5 mm): 2-5x fewer iterations, 1.2-1.7x less time cold.

Chord polish (``solve(..., polish="chord")``, ``chord``): instead of Newton's factorizations,
chord steps on the tangent at rest (factorized once and kept with the operators), Anderson-mixed,
to a largest step of ``tol_mm``; the Newton polish takes over where they diverge. Quasi-static.
With rigid tips the chord matrix adds the contact Hessian (without the tips' curvature) of the
points in contact, refactorized as they change or the steps stop contracting (counted in
``extra["chord_refactorizations"]``); steps that move points into or out of contact are
backtracked on the energy. Measured (same bench, 1.7k-50k tets, 4 mm on all four): within 1e-4 mm
of the reference, cold 4.3-7.3x faster than its Newton, warm 3.5-5.3x. Its steps are counted
in ``extra["chord_iterations"]``.

Large prescribed motions (e.g. 15 mm pushes) are applied in load steps of at most ``step_mm``;
each step moves the boundary and carries the interior along (tangent or harmonic lift), runs
ADMM (``max_iter`` per step) and, with ``polish``, Newton. When the ADMM state of a step is
outside Newton's basin (inverted elements along the Newton path), the polish restarts from the
step's lifted start state; such restarts are listed in ``extra["polish_restarts"]`` (then that
step's equilibrium is Newton's, not ADMM's, work).

Rigid tips (``contact``): frictionless indenters (sphere, rounded punch) press with the
reference's discrete contact energy (the same penalty, contact rule and tip start, taken from the
Case as the reference takes them), as consensus blocks beside the elements: the x-step matrix
keeps its scalar structure, the z-step of a block is closed-form, the polish adds the contact's
exact Hessian (without the tips' curvature until a full Newton step is taken). A load step moves
no tip by more than ``tip_step`` of its radius, and one whose polish does not converge is cut
back. Each solve reports its tips in ``SolveResult.indenters`` as the reference does.

Boundary conditions (``constraints``): prescribed dofs (fixed, displacement, affine,
axis-aligned sliding) are eliminated; oblique sliding u.n = g by a per-vertex change of basis
(exact). Tractions and gravity enter as external forces (``case.external_forces``) in the x-step.

Modules: ``mechanics`` (kinematics, material laws, energy, forces, tangent), ``constraints``,
``operators`` (D, weights, mass, x-step matrix and its CPU solver), ``contact`` (rigid
tips), ``factor`` and ``amg``
(x-step and tangent solvers), ``kernel_c`` and ``kernel_array`` (the element pass per
backend), ``backends`` (devices), ``loop`` (iterations, stopping, history), ``polish``
(Newton, lifts), ``chord`` (the chord polish), ``polisher`` (the polish a solve runs: Newton,
or chord steps with Newton where they fail), ``dynamics`` (implicit Euler), ``options`` (a
solve's options, checked), ``driver`` (``solve``: operators, load or time steps, the result).

Tunables (PCG_MIN and XSTEP_TOL in ``operators``, CHUNK in ``kernel_array``, USE_CKERNEL in
``kernel_c``, ARRAY_XSTEP_RTOL in ``backends``, ...) are set on the module that defines them.
This package exposes the solver and what a caller builds with it; the iteration's parts are
imported from their modules.

Units: mm, kPa, mN, kg, s; energy uJ = kPa mm^3 = mN mm.
"""
from __future__ import annotations

from .backends import DEVICES, GpuUnavailableError, array_module, require_device
from .contact import require_modeled
from .driver import solve
from .dynamics import ImplicitEuler
from .kernel_c import use_kernel
from .mechanics import element_kinematics, internal_forces, strain_energy, tangent_stiffness
from .operators import AdmmOperators, prepare

__all__ = [
    "DEVICES",
    "AdmmOperators",
    "GpuUnavailableError",
    "ImplicitEuler",
    "array_module",
    "element_kinematics",
    "internal_forces",
    "prepare",
    "require_device",
    "require_modeled",
    "solve",
    "strain_energy",
    "tangent_stiffness",
    "use_kernel",
]
