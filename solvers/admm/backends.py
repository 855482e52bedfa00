"""Where the ADMM iterations run (``solve(..., device=...)``):

* ``"cpu"`` (default): the element pass in the compiled kernel (``kernel_c``; numpy's
  ``kernel_array`` without a C compiler) and the x-step by the operators' factorization (SuperLU,
  or AMG-preconditioned CG on large meshes).
* ``"gpu"``: the array backend on CuPy, float64: element pass (``kernel_array``) and x-step on
  the GPU. A prefactored sparse Cholesky is not available on CuPy in general, so the x-step is
  iterative. Where the CPU path solves it by AMG-preconditioned CG (PCG_MIN free vertices and
  more, no oblique sliding) the same hierarchy and iteration run on the device
  (``amg_array``): warm-started, a few V-cycles per x-step, the CPU path's stopping rules.
  Otherwise it is conjugate gradients with a Jacobi preconditioner on the reduced x-step matrix
  K = Z^T (D^T W^2 D + M/dt^2) Z (cuSPARSE products), warm-started from the previous iterate and
  stopped at a relative residual |K q - b| <= ARRAY_XSTEP_RTOL |b| (1e-10). The data stay on
  the device between iterations; only the residual maxima (one number each) come back. Setup
  (operators, boundary lift, start state), the Newton polish and the final checks run on the
  host. Needs the optional extra ``gpu`` (``pip install 'tissue-reference[gpu]'``, CuPy for
  CUDA 12) and an NVIDIA GPU; without them ``GpuUnavailableError`` says so.
* ``"array-cpu"``: the same array backend on numpy (for tests and benchmarks: it runs the GPU
  code path on a machine without a GPU).

The x-step matrix of the array backend is the exact one, so its fixed point (the answer) is the
CPU path's; with the default tolerance the iterates agree with the CPU path's to about 1e-9
relative after 100 iterations on the phantom (``tests/test_admm_backend.py``)."""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import CaseError, TissueError

from . import amg_array, operators
from .kernel_array import ArrayElements, NumpyElements, zstep_for
from .kernel_c import KernelElements, use_kernel
from .operators import XSTEP_TOL

DEVICES = ("cpu", "gpu")  # the choices offered to users ("array-cpu": tests and benchmarks)
ARRAY_XSTEP_RTOL = 1e-10  # array backend x-step: CG to |K q - b| <= this * |b|
ARRAY_XSTEP_MAXIT = 20000  # array backend x-step: CG iterations at most
GPU_EXTRA = "pip install 'tissue-reference[gpu]'"


class GpuUnavailableError(TissueError, RuntimeError):
    """``device="gpu"`` was asked for, but CuPy or a usable CUDA GPU is missing."""


def _no_gpu(why: str) -> GpuUnavailableError:
    return GpuUnavailableError(
        f"device 'gpu': no GPU found for the ADMM solver ({why}); install the optional extra "
        f"'gpu' (CuPy for CUDA 12: {GPU_EXTRA}) on a machine with an NVIDIA GPU, or use "
        f"device 'cpu'")


def array_module(device: str):
    """The array module of ``device``: numpy for "array-cpu", cupy for "gpu" (checked: CuPy
    importable and at least one CUDA device), None for "cpu". GpuUnavailableError when "gpu"
    cannot run here, CaseError for an unknown device."""
    if device == "cpu":
        return None
    if device == "array-cpu":
        return np
    if device != "gpu":
        raise CaseError(f"unknown ADMM device {device!r}; devices: {', '.join(DEVICES)}")
    try:
        import cupy
        import cupyx.scipy.sparse  # noqa: F401
    except Exception as exc:  # noqa: BLE001  (not installed, or its CUDA libraries missing)
        raise _no_gpu(f"CuPy is not importable: {type(exc).__name__}: {exc}") from None
    try:
        count = int(cupy.cuda.runtime.getDeviceCount())
    except Exception as exc:  # noqa: BLE001  (no driver, no device)
        raise _no_gpu(f"CuPy {cupy.__version__} sees no CUDA device: {exc}") from None
    if count < 1:
        raise _no_gpu(f"CuPy {cupy.__version__} sees no CUDA device")
    return cupy


def require_device(device: str) -> str:
    """``device`` when it can run here; else GpuUnavailableError / CaseError (see
    ``array_module``)."""
    array_module(device)
    return device


def backend(ops, device: str = "cpu"):
    """The backend of ``device`` for the operators ``ops``."""
    xp = array_module(device)
    return _HostBackend(ops) if xp is None else _ArrayBackend(ops, xp, device)


class _HostBackend:
    """``device="cpu"``: host arrays, the compiled element pass (numpy without a compiler) and
    the operators' x-step solver."""

    xp = np
    device = "cpu"
    cg_iterations = None
    dev = None   # the operators stay the host's (scipy)

    def __init__(self, ops):
        self.ops = ops

    put = staticmethod(np.asarray)
    get = staticmethod(np.asarray)

    def harmonic(self, rhs):
        """Exact solve Mx q = rhs on the reduced unknowns (host in, host out)."""
        return self.ops.lu.solve(rhs)

    def zstep(self, rho):
        return zstep_for(self.ops, rho)

    def elements(self, zstep, up, F, lam):
        kernel = use_kernel() and self.ops.law.kernel
        return (KernelElements if kernel else NumpyElements)(self.ops, zstep, up, F, lam)

    def xstep(self, rhs, q, tol_mm):
        return self.ops.lu.step(rhs, q, XSTEP_TOL * tol_mm)

    def step_norm(self, dq):
        return self.ops.step_norm(dq)

    @property
    def inexactness(self):
        return self.ops.lu.inexactness


def _csr_nbytes(M) -> int:
    """Bytes of M as CSR with float64 values and int32 indices."""
    return 12 * M.nnz + 4 * M.shape[0]


class _DeviceOperators:
    """The operators the array backend needs, in the arrays of ``xp``: DZ, DZtW and Z (CSR), and
    the x-step's: the CPU path's AMG hierarchy where it has one, else the reduced x-step matrix
    K = Z^T Mx Z (CSR) and its inverse diagonal for Jacobi-CG; ``h`` stays on the host (the
    element pass copies h^2)."""

    def __init__(self, ops, xp):
        self.xp = xp
        if xp is np:
            from scipy import sparse

            self.put, self.get = np.asarray, np.asarray
        else:
            from cupyx.scipy import sparse

            self.put, self.get = xp.asarray, xp.asnumpy
        red = ops.red
        self.sparse = sparse.csr_matrix   # host scipy matrix -> this module's CSR
        self.DZ = sparse.csr_matrix(ops.DZ)
        self.DZtW = sparse.csr_matrix(ops.DZtW)
        self.Z = sparse.csr_matrix(red.Z.tocsr())
        self.h = ops.h
        self.nbytes = sum(_csr_nbytes(M) for M in (ops.DZ, ops.DZtW, red.Z))
        self.amg = self.amg_shape = None
        if red.separable and len(red.plain_dofs) >= operators.PCG_MIN * ops.d:
            lu = ops.lu    # the CPU path's x-step: its AMG hierarchy where it has one
            if lu.whole is not None and amg_array.usable(lu.groups[0][0]):
                self.amg = amg_array.ArrayAmgPcg(lu.groups[0][0], xp)
                self.amg_shape = lu.whole
                self.nbytes += self.amg.nbytes
        self.K = self.dinv = None
        if self.amg is None:   # the Jacobi-CG x-step's matrix, only where it is taken
            K = (red.ZT @ ops.Mx @ red.Z).tocsr()
            self.K = sparse.csr_matrix(K)
            self.dinv = self.put(1.0 / K.diagonal())
            self.nbytes += _csr_nbytes(K) + 8 * K.shape[0]


class _ArrayBackend:
    """The array backend (``device`` "gpu" or "array-cpu"): element pass ``ArrayElements`` and
    a Jacobi-preconditioned CG x-step, both on the arrays of ``xp``."""

    def __init__(self, ops, xp, device):
        self.ops, self.xp, self.device = ops, xp, device
        dev = ops.device_data.get(device)
        if dev is None:
            dev = ops.device_data[device] = _DeviceOperators(ops, xp)
        self.dev = dev
        self.put, self.get = dev.put, dev.get
        self.cg_iterations = 0
        self.inexactness = 0.0  # largest vertex update (mm) of the last CG iteration

    def harmonic(self, rhs):
        if self.dev.amg is not None:
            return self.get(self._amg(self.put(rhs), None, 0.0))
        q = self._pcg(self.put(rhs), self.xp.zeros(len(rhs)))
        return self.get(q)

    def zstep(self, rho):
        return zstep_for(self.ops, rho, xp=self.xp)

    def elements(self, zstep, up, F, lam):
        return ArrayElements(self.ops, zstep, up, F, lam, dev=self.dev)

    def xstep(self, rhs, q, tol_mm):
        """The x-step from the previous iterate q: the AMG-PCG step to vertex updates below
        XSTEP_TOL * tol_mm (mm) where the CPU path takes it, else Jacobi-CG to the relative
        residual ARRAY_XSTEP_RTOL (``tol_mm`` not used)."""
        if self.dev.amg is not None:
            return self._amg(rhs, q, XSTEP_TOL * tol_mm)
        return self._pcg(rhs, q.copy())

    def _amg(self, rhs, q, tol_mm):
        """AMG-PCG on the reduced unknowns (component-major: one column per component); q None:
        solved from zero to the relative residual amg.SOLVE_RTOL."""
        amg, (nv, nc) = self.dev.amg, self.dev.amg_shape
        before = amg.iterations
        B = rhs.reshape(nc, nv).T
        X = amg.solve(B) if q is None else amg.step(B, q.reshape(nc, nv).T, tol_mm)
        self.cg_iterations += amg.iterations - before
        self.inexactness = amg.last_update
        return self.xp.ascontiguousarray(X.T).reshape(-1)

    def step_norm(self, dq):
        """Largest vertex displacement (mm) of the reduced increment dq."""
        xp = self.xp
        du = (self.dev.Z @ dq).reshape(-1, self.ops.d)
        return float(xp.sqrt(xp.einsum("ij,ij->i", du, du).max()))

    def _pcg(self, b, x):
        """Jacobi-preconditioned conjugate gradients on K x = b from x (updated in place) to
        |b - K x| <= ARRAY_XSTEP_RTOL |b| (recursive residual), at most ARRAY_XSTEP_MAXIT
        iterations; zero iterations when x already satisfies it."""
        K, dinv = self.dev.K, self.dev.dinv
        r = b - K @ x
        stop2 = ARRAY_XSTEP_RTOL ** 2 * float(b @ b)
        rr = float(r @ r)
        dx, it = None, 0
        if rr > stop2:
            z = dinv * r
            p = z.copy()
            rz = r @ z
            for it in range(1, ARRAY_XSTEP_MAXIT + 1):
                Kp = K @ p
                alpha = rz / (p @ Kp)
                dx = alpha * p
                x += dx
                r -= alpha * Kp
                if float(r @ r) <= stop2:
                    break
                z = dinv * r
                rzn = r @ z
                p *= rzn / rz
                p += z
                rz = rzn
        self.cg_iterations += it
        self.inexactness = 0.0 if dx is None else self.step_norm(dx)
        return x
