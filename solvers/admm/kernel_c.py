"""The element pass of an ADMM iteration in the compiled kernel (``admm_kernel.c``, built on first
use by ``solvers.ckernel``): gather of D u, z-step, dual update, residuals and the scatter of
the next x-step data, in one pass over the element arrays. This is the default (``device="cpu"``)
element pass; ``kernel_array`` holds the same arithmetic on numpy/CuPy arrays. And the P1
internal forces (``KernelForces``) the polishes evaluate at every step."""
from __future__ import annotations

import numpy as np

from tissue_reference.solvers import ckernel

from .constraints import vertex_rank


def _det_rows(F, d):
    """det of the matrices whose entries (i, j) are the rows d i + j of F (d*d, k)."""
    if d == 2:
        return F[0] * F[3] - F[1] * F[2]
    return (F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6])
            + F[2] * (F[3] * F[7] - F[4] * F[6]))


USE_CKERNEL = True  # compiled element loop when a C compiler is usable (see use_kernel)


def use_kernel() -> bool:
    """Whether the ADMM loop runs its element-local work (z-step, dual update, residuals) in the
    compiled kernel (``admm_kernel.c``, built on first use; see ``solvers.ckernel``). False
    (the numpy loop, same arithmetic) when no C compiler is usable, when USE_CKERNEL is False
    or with the environment variable TISSUE_NO_CKERNEL=1."""
    return USE_CKERNEL and ckernel.load() is not None


class KernelElements:
    """The same element work in one call of the compiled ``admm_iteration`` (admm_kernel.c):
    gather of D u from the full displacement, z-step, dual update, residuals and the scatter of
    D^T W (z - lam + I) into a node vector, in one pass over the element arrays. F and lam live
    in the kernel's blocked layout (``_to_blocks``) and are updated in place; the ``F`` and
    ``lam`` properties give them back as (d, d, m)."""

    def __init__(self, ops, zstep, up, F, lam):
        self.ffi, self.lib = ckernel.load()
        d, m = ops.d, ops.m
        self.ops, self.zstep, self.d, self.m, self.up = ops, zstep, d, m, up
        self.blk = int(self.lib.admm_block_size())
        kd = getattr(ops, "_kernel_data", None)
        if kd is None:
            # vertices renumbered by their reverse Cuthill-McKee rank (the elements are sorted by
            # it too), so that the gather of u and the scatter of f stay local in memory
            eo, rank = ops.elem_order, vertex_rank(ops.mesh)
            plain = ops.red.plain_dofs
            kd = ops._kernel_data = (
                np.ascontiguousarray(rank[ops.mesh.cells[eo]], dtype=np.int32),
                np.ascontiguousarray(ops.kin.G[eo]), np.ascontiguousarray(ops.rho * ops.kin.V[eo]),
                np.ascontiguousarray(ops.h ** 2), rank, np.argsort(rank),
                d * rank[plain // d] + plain % d if ops.red.separable else None)
        self.cells, self.G, self.wv, self.h2, self.rank, self.order, self.idx = kd
        self.Fb, self.lamb = self._to_blocks(F), self._to_blocks(lam)
        self.r, self.dsq = np.empty(m), np.empty(m)
        self.u = np.ascontiguousarray(up.reshape(-1, d)[self.order]).reshape(-1)  # internal order
        self.f = np.zeros(ops.N)
        self.model = 0 if ops.law.model == "linear-elastic" else 1
        self._data = None
        p = self._ptr
        self._args = (p(self.cells, "int *"), p(self.G), p(self.wv), p(self.h2), p(self.u),
                      p(self.Fb), p(self.lamb), p(self.r), p(self.dsq), p(self.f))

    def _to_blocks(self, A):
        """(d, d, m) -> the kernel's (ceil(m / blk), d*d, blk) layout (padding never read)."""
        dd, m, blk = self.d * self.d, self.m, self.blk
        nb = -(-m // blk)
        out = np.zeros((dd, nb * blk))
        out[:, :m] = A.reshape(dd, m)
        return np.ascontiguousarray(out.reshape(dd, nb, blk).transpose(1, 0, 2))

    def _from_blocks(self, B):
        d, m = self.d, self.m
        return np.ascontiguousarray(B.transpose(1, 0, 2).reshape(d * d, -1)[:, :m]).reshape(d, d, m)

    @property
    def F(self):
        return self._from_blocks(self.Fb)

    @property
    def lam(self):
        return self._from_blocks(self.lamb)

    def _ptr(self, a, kind="double *"):
        if not a.flags.c_contiguous:
            raise TypeError("ADMM kernel: arrays must be C-contiguous")
        return self.ffi.cast(kind, a.ctypes.data)

    def xdata(self):
        if self._data is None:  # first iteration, or after a rho change
            self._data = self.ops.DZtW @ (self.F - self.lam).reshape(-1)
        return self._data

    def halve_dual(self):
        self.lamb *= 0.5
        self._data = None

    def state(self):
        """(F, lam) as one vector (the blocked layout's, padding included): the ADMM iteration's
        fixed-point variables (``loop.Anderson``)."""
        return np.concatenate((self.Fb.reshape(-1), self.lamb.reshape(-1)))

    def admissible(self, x) -> bool:
        """Whether every element's F in the state vector x has det F > 0 (linear elasticity:
        always)."""
        if self.model == 0:
            return True
        d, m = self.d, self.m
        F = x[:self.Fb.size].reshape(-1, d * d, self.blk).transpose(1, 0, 2).reshape(d * d, -1)
        return bool(np.all(_det_rows(F[:, :m], d) > 0))

    def set_state(self, x):
        """Set (F, lam) from a vector of ``state``'s layout."""
        n = self.Fb.size
        self.Fb.reshape(-1)[...] = x[:n]
        self.lamb.reshape(-1)[...] = x[n:]
        self._data = None

    def update(self, q):
        ops, zs = self.ops, self.zstep
        d = self.d
        if self.idx is not None:  # u = up + Z q, Z a selection of plain dofs
            self.u[self.idx] = q
        else:
            self.u.reshape(-1, d)[...] = (self.up + ops.red.Z @ q).reshape(-1, d)[self.order]
        self.f[...] = 0.0
        self.lib.admm_iteration(
            self.model, self.d, self.m, ops.law.mu, ops.law.kappa, zs.rho,
            getattr(zs, "f_dev", 0.0), getattr(zs, "f_vol", 0.0), zs.rounds, zs.small_step,
            *self._args)
        if self.idx is not None:
            self._data = self.f[self.idx]
        else:
            self._data = ops.red.ZT @ self.f.reshape(-1, d)[self.rank].reshape(-1)
        return self.r, self.dsq


class KernelForces:
    """The P1 internal forces at a displacement (the elastic energy's gradient, mN, node-major)
    in one compiled pass (``p1_forces`` of admm_kernel.c): the gather of u, the stress of
    ``mechanics.Law.stress`` per element and the scatter, without the numpy path's (m, d, d)
    arrays and sparse products; and the smallest det F, for the validity test."""

    def __init__(self, ops):
        self.ffi, self.lib = ckernel.load()
        kin, law = ops.kin, ops.law
        self.dofs = np.ascontiguousarray(kin.dofs, dtype=np.int32)
        self.G = np.ascontiguousarray(kin.G, dtype=float)
        self.V = np.ascontiguousarray(kin.V, dtype=float)
        # p1_forces' leading arguments: model (0 linear, 1 Neo-Hookean), d, m, mu, kappa, lambda
        self._scalars = (0 if law.model == "linear-elastic" else 1, ops.d, ops.m,
                         float(law.mu), float(law.kappa), float(law.lmbda))
        cast = self.ffi.cast
        self._fixed = (cast("int *", self.dofs.ctypes.data), cast("double *", self.G.ctypes.data),
                       cast("double *", self.V.ctypes.data))

    def add(self, u, out) -> float:
        """out += the internal forces at u (mm, (N,)); returns the smallest det F (1 for linear
        elasticity; NaN where u is not finite)."""
        u = np.ascontiguousarray(u, dtype=float)
        if not (out.flags.c_contiguous and out.dtype == np.float64):
            raise TypeError("KernelForces.add: out must be a C-contiguous float64 array")
        cast = self.ffi.cast
        return float(self.lib.p1_forces(*self._scalars, *self._fixed,
                                        cast("double *", u.ctypes.data),
                                        cast("double *", out.ctypes.data)))
