"""The ADMM's array backend (solvers/admm/backends.py and kernel_array.py: element pass and a
Jacobi-preconditioned CG x-step written against numpy or CuPy) against the default CPU path
(compiled kernel, SuperLU x-step): the same iterates, the same converged answer; the GPU device
refused with a clear error (in the API and in ``tissue solve``) where CuPy or a GPU is missing.

Without a GPU the array code runs on numpy (``device="array-cpu"``). Its x-step is iterative:
CG to a relative residual ARRAY_XSTEP_RTOL = 1e-10, which keeps its iterates within about
1e-9 (relative) of the direct x-step's after 100 iterations on the phantom; the tests below
ask for 1e-8. Tests on the GPU itself skip (with the reason) where CuPy finds no GPU."""
import sys
import types

import numpy as np
import pytest

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box, rectangle
from tissue_reference.model.case import Boundary, Case, Material, load_case
from tissue_reference.solvers import admm
from tissue_reference.solvers.admm import backends, kernel_array, operators
from tissue_reference.tissue.cli import main

CASE_TOML = "meshes/cases/phantom.toml"
PUSHES = {"A1": 5.0, "A2": 5.0, "A3": 5.0, "A4": 5.0}
ITERATES = {"polish": False, "max_iter": 100, "tol_mm": 1e-30, "load_steps": 1}


def _gpu_missing():
    try:
        admm.array_module("gpu")
    except admm.GpuUnavailableError as exc:
        return str(exc)
    return None


GPU_MISSING = _gpu_missing()
needs_gpu = pytest.mark.skipif(GPU_MISSING is not None, reason=f"no GPU: {GPU_MISSING}")
without_gpu = pytest.mark.skipif(GPU_MISSING is None, reason="CuPy finds a GPU here")


@pytest.fixture(scope="module")
def phantom():
    return load_case(CASE_TOML)


@pytest.fixture(scope="module")
def phantom12():
    return load_case(CASE_TOML, size=12.0)


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


def _same_iterates(ref, res, tol=1e-8):
    assert res.extra["admm_iterations"] == ref.extra["admm_iterations"]
    assert res.history.get("rho_changes") == ref.history.get("rho_changes")
    assert _rel(res.u, ref.u) <= tol
    for key in ("primal", "dual"):
        assert _rel(np.array(res.history[key]), np.array(ref.history[key])) <= 1e-5, key


def test_array_backend_on_numpy_gives_the_kernels_iterates_on_the_phantom(phantom):
    """100 iterations of one 5 mm load step with all four actuators: u within 1e-8 (relative)
    of the compiled kernel's, same rho doublings."""
    assert backends.ARRAY_XSTEP_RTOL == 1e-10
    ref = admm.solve(phantom, pushes=PUSHES, **ITERATES)
    res = admm.solve(phantom, pushes=PUSHES, device="array-cpu", **ITERATES)
    assert ref.extra["device"] == "cpu" and res.extra["device"] == "array-cpu"
    assert ref.extra["admm_iterations"] == 100
    assert res.extra["xstep_cg_iterations"] > 100  # the x-step is the CG one
    assert admm.prepare(phantom.with_pushes(PUSHES)).device_data["array-cpu"].K is not None
    _same_iterates(ref, res)


def _box_case(mesh, model="neo-hookean", boundaries=None):
    b = boundaries or [Boundary("xmin", "fixed"),
                       Boundary("xmax", "displacement", value=(1.5, 0.5, -0.3)[:mesh.gdim])]
    return Case(mesh, Material(model=model, E=6.0, nu=0.45), boundaries=b)


@pytest.mark.parametrize("kind", ["3d-linear", "2d-neo-hookean", "3d-oblique-sliding",
                                  "3d-dynamics"])
def test_array_backend_on_numpy_gives_the_kernels_iterates(kind):
    """Linear elasticity, plane strain, oblique sliding (coupled x-step matrix) and implicit
    Euler (mass term in the x-step)."""
    kw = {"polish": False, "tol_mm": 1e-30, "max_iter": 60, "lift": False}
    if kind == "2d-neo-hookean":
        case = _box_case(rectangle(1.5))
    elif kind == "3d-oblique-sliding":
        n = np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)
        case = _box_case(box(4.0), "neo-hookean", [
            Boundary("xmin", "fixed"), Boundary("xmax", "displacement", value=(1.5, 0.3, -0.3)),
            Boundary("ymin", "sliding", normal=n.tolist(), value=0.0)])
    else:
        case = _box_case(box(4.0), "linear-elastic" if kind == "3d-linear" else "neo-hookean")
    if kind == "3d-dynamics":
        kw = {**kw, "dynamics": admm.ImplicitEuler(dt=0.05, steps=2)}
    _same_iterates(admm.solve(case, **kw), admm.solve(case, device="array-cpu", **kw))


@pytest.mark.parametrize("model", ["neo-hookean", "linear-elastic"])
def test_element_pass_branches_of_cupy_on_a_numpy_stand_in(model):
    """The branches the element pass takes on CuPy (einsum without ``out``, no floating-point
    error state, all elements in one block, device copies of the operators), run on a stand-in
    module that is numpy without those features, from a strained state (line searches and
    repeated rounds run): numpy's element pass, element by element."""
    xp = types.SimpleNamespace(**{n: getattr(np, n) for n in dir(np) if not n.startswith("_")})

    def einsum(*operands, **kw):
        assert "out" not in kw
        return np.einsum(*operands, **kw)

    xp.einsum = einsum
    del xp.errstate
    case = _box_case(box(4.0), model)
    ops = admm.prepare(case)
    rng = np.random.default_rng(3)
    d, m = ops.d, ops.m
    up = operators.particular(case, ops)
    F = np.eye(d)[:, :, None] + 0.35 * rng.standard_normal((d, d, m))
    F[:, :, :5] = np.eye(d)[:, :, None] * 0.2
    lam = 0.2 * rng.standard_normal((d, d, m))
    q = rng.standard_normal(ops.nq)
    dev = types.SimpleNamespace(DZ=ops.DZ, DZtW=ops.DZtW, h=ops.h, put=np.array)
    out = []
    for mod, where in ((np, None), (xp, dev)):
        el = kernel_array.ArrayElements(ops, kernel_array.ZStep(ops, 2.0 * ops.rho, xp=mod), up,
                                              F.copy(), lam.copy(), dev=where)
        with np.errstate(invalid="ignore", divide="ignore"):
            r, dsq = el.update(q)
        out.append((r.copy(), dsq.copy(), np.array(el.F), np.array(el.lam), el.xdata()))
    for a, b in zip(*out):
        assert np.all(np.isfinite(a))
        assert np.abs(a - b).max() <= 1e-13 * max(1.0, np.abs(a).max())


def test_plain_admm_fixed_point_is_the_cpu_paths(phantom12):
    """Without the polish the ADMM fixed point itself: the same as the CPU path's."""
    kw = {"pushes": {"A1": 3.0, "A3": 3.0}, "polish": False, "tol_mm": 1e-6, "max_iter": 5000}
    cpu = admm.solve(phantom12, **kw)
    arr = admm.solve(phantom12, device="array-cpu", **kw)
    assert cpu.converged and arr.converged
    assert np.abs(arr.u - cpu.u).max() < 1e-5


@without_gpu
def test_gpu_device_without_cupy_or_gpu_is_a_clear_error(monkeypatch):
    case = _box_case(box(5.0))
    with pytest.raises(admm.GpuUnavailableError,
                       match=r"no GPU found.*tissue-reference\[gpu\].*device 'cpu'"):
        admm.solve(case, device="gpu")
    # CuPy importable but no CUDA device behind it
    cupy = types.ModuleType("cupy")
    cupy.__version__ = "0-test"

    def no_device():
        raise RuntimeError("cudaErrorNoDevice: no CUDA-capable device is detected")

    cupy.cuda = types.SimpleNamespace(runtime=types.SimpleNamespace(getDeviceCount=no_device))
    cupyx = types.ModuleType("cupyx")
    for name, mod in (("cupy", cupy), ("cupyx", cupyx), ("cupyx.scipy", cupyx),
                      ("cupyx.scipy.sparse", cupyx)):
        monkeypatch.setitem(sys.modules, name, mod)
    with pytest.raises(admm.GpuUnavailableError, match=r"sees no CUDA device.*\[gpu\]"):
        admm.solve(case, device="gpu")


def test_unknown_device_is_a_case_error():
    with pytest.raises(CaseError, match=r"unknown ADMM device 'tpu'"):
        admm.solve(_box_case(box(5.0)), device="tpu")


@without_gpu
def test_tissue_solve_device_gpu_without_a_gpu_is_one_line_exit_2(capsys):
    rc = main(["solve", CASE_TOML, "--solver", "admm", "--device", "gpu", "--size", "12"])
    _, err = capsys.readouterr()
    assert rc == 2
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "tissue solve: error: device 'gpu': no GPU found" in err
    assert "tissue-reference[gpu]" in err


def test_tissue_solve_device_applies_to_admm_only(capsys):
    rc = main(["solve", CASE_TOML, "--solver", "fem", "--device", "gpu", "--size", "12"])
    _, err = capsys.readouterr()
    assert rc == 2 and "--device gpu applies to the ADMM solver" in err


@pytest.fixture(scope="module")
def large_box():
    """A block with more free vertices than PCG_MIN, so the CPU path's x-step is AMG-PCG."""
    from tissue_reference.meshes.builders import structured_box

    m = structured_box(17)
    return Case(m, Material(model="neo-hookean", E=6.0, nu=0.45),
                boundaries=[Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=(1.0, 0.5, -0.3))])


LARGE = {"polish": False, "lift": False, "load_steps": 1, "max_iter": 40, "tol_mm": 1e-30}


def _uses_device_amg(case, device):
    return admm.prepare(case).device_data[device].amg is not None


def test_array_backend_takes_the_cpu_paths_amg_x_step_on_large_meshes(large_box):
    """Above PCG_MIN free vertices the array backend runs the CPU path's AMG-PCG x-step (its
    hierarchy, iteration and stopping rules): on numpy the iterates are the CPU path's to
    round-off, a few V-cycles per x-step, and the converged answers agree."""
    ref = admm.solve(large_box, **LARGE)
    res = admm.solve(large_box, device="array-cpu", **LARGE)
    assert _uses_device_amg(large_box, "array-cpu")
    assert admm.prepare(large_box).lu.kind == "AmgPcg"
    # the Jacobi-CG matrix is not built where the AMG x-step replaces it: no device memory
    assert admm.prepare(large_box).device_data["array-cpu"].K is None
    _same_iterates(ref, res, tol=1e-10)
    assert res.extra["xstep_cg_iterations"] <= 5 * LARGE["max_iter"]
    conv = {**LARGE, "max_iter": 500, "tol_mm": 1e-4}
    a = admm.solve(large_box, **conv)
    b = admm.solve(large_box, device="array-cpu", **conv)
    assert a.converged and b.converged
    assert b.extra["admm_iterations"] == a.extra["admm_iterations"]
    assert _rel(b.u, a.u) <= 1e-10


@needs_gpu
def test_gpu_takes_the_amg_x_step_with_the_cpu_paths_iterates(large_box):
    ref = admm.solve(large_box, **LARGE)
    res = admm.solve(large_box, device="gpu", **LARGE)
    assert _uses_device_amg(large_box, "gpu")
    _same_iterates(ref, res)


@needs_gpu
def test_gpu_gives_the_kernels_iterates_on_the_phantom(phantom):
    ref = admm.solve(phantom, pushes=PUSHES, **ITERATES)
    res = admm.solve(phantom, pushes=PUSHES, device="gpu", **ITERATES)
    assert res.extra["device"] == "gpu"
    _same_iterates(ref, res)


@needs_gpu
def test_gpu_converged_answer_matches_the_reference(phantom12):
    from tissue_reference.fem_reference import solve as fem_solve
    ref = fem_solve(phantom12, degree=1, pushes=PUSHES)
    res = admm.solve(phantom12, pushes=PUSHES, max_iter=300, device="gpu")
    assert res.converged
    assert np.abs(res.u - ref.u).max() < 1e-6
    assert res.strain_energy == pytest.approx(ref.strain_energy, rel=1e-8)


@needs_gpu
def test_tissue_solve_on_the_gpu(tmp_path, capsys):
    rc = main(["solve", CASE_TOML, "--solver", "admm", "--device", "gpu", "--size", "12",
               "--push", "A1=3", "-q"])
    out, _ = capsys.readouterr()
    assert rc == 0 and "admm converged=True" in out
