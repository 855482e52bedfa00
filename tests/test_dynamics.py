"""Implicit-Euler dynamics of the reference (fem_reference.dynamics, seed 000 eq. 5) against
independent answers: the closed-form modal solution of the discrete linear recurrence, the
ADMM's dynamic mode on the same Case, and the quasi-static reference in the limit of large dt.

Closed form (linear elasticity, free dofs, M and K written here independently with numpy):
    (M / dt^2) (u_{n+1} - u_n - dt v_n) + K u_{n+1} = f,    v_{n+1} = (u_{n+1} - u_n) / dt.
With K phi_k = omega_k^2 M phi_k (M-orthonormal) and u = K^-1 f + sum_k a_k phi_k, each a_k
obeys (1 + dt^2 omega^2) a_{n+1} - 2 a_n + a_{n-1} = 0, a_{-1} = a_0 - dt b_0, whose roots are
1 / (1 -+ i dt omega) = rho e^{+-i theta}, rho = (1 + dt^2 omega^2)^(-1/2), theta = atan(dt omega):
    a_n = rho^n (a_0 cos(n theta) + (b_0 / omega) sin(n theta)).
Units: mm, kPa, mN, kg, s.
"""
import numpy as np
import pytest
import scipy.linalg as sla
from fem_checks import linear_p1_stiffness

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.fem_reference.dynamics import simulate
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material
from tissue_reference.solvers import admm

G = 9810.0  # mm/s^2
RHO = 1.0e-6  # kg/mm^3


@pytest.fixture(scope="module")
def cube():
    return box(4.0)


def _volumes(mesh):
    X = mesh.points[mesh.cells]
    return np.abs(np.linalg.det(X[:, 1:] - X[:, :1])) / 6.0


def _mass(mesh, kind):
    """P1 mass (kg), node-major: lumped density V/4 per vertex and cell, or consistent
    density V/20 (1 + delta_ab)."""
    n = mesh.n_vertices
    V = _volumes(mesh)
    if kind == "lumped":
        m = np.zeros(n)
        np.add.at(m, mesh.cells.ravel(), np.repeat(RHO * V / 4.0, 4))
        return np.diag(np.repeat(m, 3))
    Ms = np.zeros((n, n))
    local = (np.ones((4, 4)) + np.eye(4)) / 20.0
    for c, v in zip(mesh.cells, V):
        Ms[np.ix_(c, c)] += RHO * v * local
    return np.kron(Ms, np.eye(3))


def _closed_form(case, kind, dt, steps, f, v0):
    """Vertex displacements (steps + 1, n, 3) of the modal solution (module docstring)."""
    mesh = case.mesh
    K = linear_p1_stiffness(mesh, case.material.E, case.material.nu).toarray()
    M = _mass(mesh, kind)
    free = case.free_dofs()
    Kf, Mf, ff = K[np.ix_(free, free)], M[np.ix_(free, free)], f[free]
    w2, Phi = sla.eigh(Kf, Mf)  # Phi^T M Phi = I
    omega = np.sqrt(w2)
    us = np.linalg.solve(Kf, ff)
    a0 = Phi.T @ Mf @ (0.0 - us)
    b0 = Phi.T @ Mf @ v0.ravel()[free]
    rho = 1.0 / np.sqrt(1.0 + (dt * omega) ** 2)
    theta = np.arctan(dt * omega)
    out = np.zeros((steps + 1, mesh.n_vertices * 3))
    for k in range(steps + 1):
        a = rho ** k * (a0 * np.cos(k * theta) + b0 / omega * np.sin(k * theta))
        out[k, free] = us + Phi @ a
    return out.reshape(steps + 1, -1, 3), omega


def _gravity_cube(mesh, model="linear-elastic"):
    return Case(mesh, Material(model, E=6.0, nu=0.3, density=RHO),
                boundaries=(Boundary("zmin", "fixed"),), gravity=(G, 0.0, 0.0), name="cube")


@pytest.mark.parametrize("kind", ["lumped", "consistent"])
def test_suddenly_applied_gravity_follows_the_closed_form_modal_recurrence(cube, kind):
    """Sideways gravity applied at t = 0 to a cube fixed at its base, with an initial velocity:
    every step equals the modal closed form to round-off."""
    case = _gravity_cube(cube)
    dt, steps = 2e-3, 12
    rng = np.random.default_rng(0)
    v0 = 50.0 * rng.standard_normal((cube.n_vertices, 3))  # mm/s
    v0.reshape(-1)[case.constraints.dofs] = 0.0
    f = case.external_forces()
    exact, omega = _closed_form(case, kind, dt, steps, f, v0)
    assert 0.2 < dt * omega.min() < 2.0  # the lowest mode is resolved, neither frozen nor lost
    res = simulate(case, dt=dt, steps=steps, mass=kind, initial_velocity=v0)
    scale = np.abs(exact).max()
    assert scale > 0.05  # mm: a visible motion
    assert np.abs(res.u - exact).max() <= 1e-9 * scale
    np.testing.assert_allclose(res.times, dt * np.arange(steps + 1), rtol=1e-15)
    assert res.converged.all() and res.converged.shape == (steps,)
    assert res.total_mass_kg == pytest.approx(RHO * 1000.0, rel=1e-12)
    M = _mass(cube, kind)
    for k in (0, 1, steps):
        v = res.velocity[k].ravel()
        assert res.kinetic_energy[k] == pytest.approx(0.5 * v @ M @ v, rel=1e-9)


def test_reference_dynamics_matches_admm_dynamics_step_by_step(cube):
    """Neo-Hookean cube, one face pushed suddenly and gravity: ADMM (with and without its Newton
    polish) against the reference, same lumped mass and dt, every step."""
    case = Case(cube, Material("neo-hookean", E=6.0, nu=0.45, density=RHO),
                boundaries=(Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=(1.5, 0.5, -0.5))),
                gravity=(0.0, 0.0, -G), probes=(), name="cube")
    dt, steps = 2e-3, 6
    ref = simulate(case, dt=dt, steps=steps)
    assert np.abs(ref.u[-1]).max() > 1.0
    for polish, tol, agree in ((True, 1e-5, 1e-8), (False, 1e-5, 1e-3)):
        u, v = None, None
        for k in range(1, steps + 1):
            res = admm.solve(case, initial=u, polish=polish, tol_mm=tol,
                             dynamics=admm.ImplicitEuler(dt=dt, steps=1, velocity=v))
            assert res.converged
            u, v = res.u, res.extra["velocity"]
            assert np.abs(u - ref.u[k]).max() < agree, (polish, k)
            assert np.abs(v - ref.velocity[k]).max() < agree / dt, (polish, k)
    # one N-step ADMM call gives the same end state as stepping
    whole = admm.solve(case, dynamics=admm.ImplicitEuler(dt=dt, steps=steps))
    assert np.abs(whole.u - ref.u[-1]).max() < 1e-8


def test_large_dt_reproduces_the_quasi_static_reference(cube):
    """One step of dt = 1e3 s: inertia M/dt^2 ~ 1e-12 of the stiffness; the quasi-static solve on
    the same solver afterwards is unaffected by the dynamics (its inertia term removed)."""
    case = Case(cube, Material("neo-hookean", E=6.0, nu=0.45, density=RHO),
                boundaries=(Boundary("zmin", "fixed"),
                            Boundary("zmax", "displacement", value=(0.5, 0.0, -1.0))),
                gravity=(0.0, 0.0, -G), name="cube")
    dyn = simulate(case, dt=1e3, steps=1)
    static = fr.solve(case, degree=1)
    assert np.abs(dyn.u[-1] - static.u).max() < 1e-8
    assert dyn.strain_energy[-1] == pytest.approx(static.strain_energy, rel=1e-8)


def test_ramped_boundary_values_move_linearly_then_hold(cube):
    case = Case(cube, Material("linear-elastic", E=6.0, nu=0.3, density=RHO),
                boundaries=(Boundary("zmin", "fixed"),
                            Boundary("zmax", "displacement", value=(0.0, 0.0, -1.0))),
                name="cube")
    res = simulate(case, dt=5e-3, steps=4, ramp_steps=2)
    top = cube.region_vertices("zmax")
    for k, s in enumerate((0.0, 0.5, 1.0, 1.0, 1.0)):
        np.testing.assert_allclose(res.u[k][top, 2], -s, atol=1e-12)
    assert np.abs(res.u[0]).max() == 0.0


def test_bad_arguments_are_refused(cube):
    case = _gravity_cube(cube)
    with pytest.raises(CaseError, match="dt"):
        simulate(case, dt=0.0, steps=1)
    with pytest.raises(CaseError, match="steps"):
        simulate(case, dt=1e-3, steps=0)
    with pytest.raises(CaseError, match="mass"):
        simulate(case, dt=1e-3, steps=1, mass="diagonal")
    with pytest.raises(CaseError, match="consistent"):
        simulate(case, dt=1e-3, steps=1, degree=2)
    with pytest.raises(CaseError, match="initial_velocity"):
        simulate(case, dt=1e-3, steps=1, initial_velocity=np.zeros((3, 3)))


BOX_TOML = """name = "box"
[mesh]
builtin = "box"
size = 5.0
[material]
model = "neo-hookean"
E = 6.0
nu = 0.45
density = 1.0e-6
[body]
gravity = [0.0, 0.0, -9810.0]
[[boundary]]
region = "xmin"
type = "fixed"
[[actuator]]
name = "A1"
region = "xmax"
direction = [-1.0, 0.0, 0.0]
[[probe]]
name = "T1"
point = [5.0, 5.0, 5.0]
"""


def test_dynamics_command_gives_the_same_trajectory_with_fem_and_admm(tmp_path, capsys):
    import json

    from tissue_reference.tissue.cli import main

    toml = tmp_path / "box.toml"
    toml.write_text(BOX_TOML)
    common = ["dynamics", str(toml), "--dt", "0.002", "--steps", "3", "--push", "A1=1", "-q"]
    assert main(common + ["--out", str(tmp_path / "fem"), "--json", str(tmp_path / "fem.json")]) \
        == 0
    assert main(common + ["--solver", "admm", "--json", str(tmp_path / "admm.json")]) == 0
    fem = json.loads((tmp_path / "fem.json").read_text())
    fast = json.loads((tmp_path / "admm.json").read_text())
    assert fem["times_s"] == pytest.approx([0.0, 0.002, 0.004, 0.006])
    assert np.abs(np.array(fem["probes"]["T1"]) - np.array(fast["probes"]["T1"])).max() < 1e-8
    assert fem["kinetic_energy_uJ"] == pytest.approx(fast["kinetic_energy_uJ"], rel=1e-6)
    assert (tmp_path / "fem" / "trajectory.pvd").is_file()
    assert len(list((tmp_path / "fem").glob("trajectory_*.vtu"))) == 4
    capsys.readouterr()
    assert main(["dynamics", str(toml), "--dt", "0.002", "--steps", "3", "--solver", "admm",
                 "--mass", "consistent"]) == 2
    assert "--mass consistent" in capsys.readouterr().err


def test_a_changed_density_reaches_the_gravity_load_of_a_cached_solver(cube):
    """Gravity scales with the density: a Case differing only in density gets its own load."""
    case = _gravity_cube(cube)
    light = fr.solve(case, degree=1)
    heavy = fr.solve(case.with_material(density=2 * RHO), degree=1)
    np.testing.assert_allclose(heavy.u, 2 * light.u, rtol=1e-9, atol=1e-12)


def test_a_step_that_does_not_converge_raises_with_the_trajectory_so_far(cube):
    case = Case(cube, Material("neo-hookean", E=6.0, nu=0.45, density=RHO),
                boundaries=(Boundary("zmin", "fixed"),), gravity=(G, 0.0, 0.0), name="cube")
    with pytest.raises(ConvergenceError, match=r"step 1/3 \(t = 0.002 s\)") as info:
        simulate(case, dt=2e-3, steps=3, settings=fr.NewtonSettings(max_iterations=1))
    assert info.value.trajectory.steps == 0
    assert np.abs(info.value.last_converged.u).max() == 0.0
