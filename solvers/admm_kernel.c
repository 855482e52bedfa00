/* One ADMM iteration's element work for solvers/admm.py, compiled: for every element, the
 * gradient of the x-step's displacement (gather), the z-step, the dual update, the residuals, and
 * the element's share of the next x-step's right-hand side (scatter), in one pass over memory.
 *
 * The same arithmetic as the numpy loop of admm._admm / admm._ZStep: F = I + z,
 * Fhat = I + D u + lam; the Neo-Hookean z-step is the safeguarded model-Newton step of
 * _ZStep._step (up to `rounds` rounds for the elements whose step the line search shortened),
 * the linear-elastic one its closed form. Element states F and lam are stored in blocks of BLK
 * elements ("array of structures of arrays", shape (ceil(m / BLK), d*d, BLK)): entry q = d i + J
 * of element k at ((k / BLK) d^2 + q) BLK + k % BLK, so that each block is one contiguous piece of
 * memory (a plain (d, d, m) layout makes 2 d^2 concurrent memory streams, more than the hardware
 * prefetchers follow: 4x slower per element on large meshes). cells (m, d+1) and G (m, d+1, d)
 * (shape-function gradients, 1/mm) in the same (internal) element order; u and f node-major
 * (d v + i).
 *
 * F and lam are updated in place: F <- F' (the new F), lam <- lam' = Fhat - F'; per element,
 * r[k] = h2[k] |lam' - lam|^2 (primal residual squared, mm^2), dsq[k] = h2[k] |F' - F|^2 (dual
 * residual squared at rho0, mm^2), and f += W_e D_e^T (F' - lam') with W_e = wv[k] (rho0 V_e):
 * f is D^T W (z - lam), the x-step's data term (accumulated: the caller zeroes it).
 *
 * model: 0 linear elasticity (closed form, f_dev, f_vol), 1 Neo-Hookean (seed eq. 14), plane
 * strain in 2D. Units: mu, kappa, rho in kPa.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "admm_kernel.h"

#define MAXD 3

/* cofactor (J F^-T), J and I1 (plane strain: |F|^2 + 1) */
static void parts(int d, const double *F, double *cof, double *J, double *I1)
{
    double s = 0.0;
    for (int q = 0; q < d * d; ++q)
        s += F[q] * F[q];
    if (d == 3) {
        for (int i = 0; i < 3; ++i) {
            int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
            for (int j = 0; j < 3; ++j) {
                int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
                cof[3 * i + j] = F[3 * i1 + j1] * F[3 * i2 + j2] - F[3 * i1 + j2] * F[3 * i2 + j1];
            }
        }
        *J = F[0] * cof[0] + F[1] * cof[1] + F[2] * cof[2];
        *I1 = s;
    } else {
        cof[0] = F[3];
        cof[1] = -F[2];
        cof[2] = -F[1];
        cof[3] = F[0];
        *J = F[0] * F[3] - F[1] * F[2];
        *I1 = s + 1.0;
    }
}

/* x^(-2/3) for 1e-6 < x < 1e6 without libm: a bit-level first guess of y = x^(-1/3) (in single
 * precision, within 4 %) and four multiply-only Newton steps y <- y (4 - x y^3) / 3 (quadratic
 * convergence: relative error below 7e-16 over that range, i.e. the last bit or two). glibc's
 * cbrt cost half of the whole element update, and it does not vectorize; this does. */
static inline double pow_m23_fast(double x)
{
    float xf = (float)x, yf;
    uint32_t u;
    memcpy(&u, &xf, sizeof u);
    u = 0x54a2fa8cu - u / 3u;
    memcpy(&yf, &u, sizeof yf);
    double y = yf;
    for (int i = 0; i < 4; ++i)
        y = y * (4.0 - x * y * y * y) * (1.0 / 3.0);
    return y * y;
}

#define FAST_RANGE(x) ((x) > 1e-6 && (x) < 1e6)

/* |x|^(-2/3) with numpy's semantics (x <= 0, NaN, inf included) */
static inline double pow_m23(double x)
{
    if (FAST_RANGE(x))
        return pow_m23_fast(x);
    double c = cbrt(1.0 / x);
    return c * c;
}

/* local objective psi(F) + rho/2 |F - Fhat|^2 (inf where J <= 0); J returned in *Jout */
static double phi(int d, const double *F, const double *Fhat, double mu, double kappa,
                  double rho, double *Jout)
{
    double cof[MAXD * MAXD], J, I1;
    parts(d, F, cof, &J, &I1);
    *Jout = J;
    if (!(J > 0.0))
        return INFINITY;
    double r2 = 0.0;
    for (int q = 0; q < d * d; ++q) {
        double t = F[q] - Fhat[q];
        r2 += t * t;
    }
    return 0.5 * mu * (pow_m23(J) * I1 - 3.0) + 0.5 * kappa * (J - 1.0) * (J - 1.0)
           + 0.5 * rho * r2;
}

/* one safeguarded model-Newton step from F into Fn; returns 1 when the step was shortened
 * (or refused) by the line search, i.e. another round may follow */
static int nh_step(int d, const double *F, const double *Fhat, double *Fn, double mu,
                   double kappa, double rho, double small_step)
{
    const int dd = d * d;
    double cof[MAXD * MAXD], J, I1, dF[MAXD * MAXD];
    const double mur = mu / rho, kr = kappa / rho;
    parts(d, F, cof, &J, &I1);
    double iJ = 1.0 / J;
    double ar = mur * pow_m23(J);               /* a / rho = mu J^(-2/3) / rho */
    double b = kr * J - kr - I1 * ar * iJ / 3.0; /* b / rho */
    double al = ar + 1.0;
    double beta = kr * (2.0 - iJ);
    if (!(beta > 0.0))
        beta = (beta == beta) ? 0.0 : beta; /* max(beta, 0); NaN propagates as in numpy */
    double cc = 0.0, cfh = 0.0;
    for (int q = 0; q < dd; ++q) {
        cc += cof[q] * cof[q];
        cfh += cof[q] * Fhat[q];
    }
    double cg = beta * (al * d * J - cfh + b * cc) / (al + beta * cc) - b;
    double dz2 = 0.0, ial = 1.0 / al;
    for (int q = 0; q < dd; ++q) {
        Fn[q] = (Fhat[q] + cg * cof[q]) * ial;
        dF[q] = Fn[q] - F[q];
        dz2 += dF[q] * dF[q];
    }
    const double ds = small_step;
    double lim = ds / sqrt(3.0) * I1 + ds * ds * sqrt(I1) + ds * ds * ds;
    if (!(J <= lim || dz2 > ds * ds))
        return 0; /* small step from a safe state: J stays > 0 */
    /* Armijo backtracking on the local objective; g:dF = -rho (alpha |dF|^2 + beta (cof:dF)^2) */
    double cd = 0.0;
    for (int q = 0; q < dd; ++q)
        cd += cof[q] * dF[q];
    double gd = -rho * (al * dz2 + beta * cd * cd);
    double Jt;
    double phi0 = phi(d, F, Fhat, mu, kappa, rho, &Jt);
    double tolr = 1e-13 * fabs(phi0);
    double alpha = 1.0, Ft[MAXD * MAXD];
    for (int it = 0; it < 40; ++it) {
        for (int q = 0; q < dd; ++q)
            Ft[q] = F[q] + alpha * dF[q];
        double ph = phi(d, Ft, Fhat, mu, kappa, rho, &Jt);
        if (Jt > 0.0 && ph <= phi0 + 1e-4 * alpha * gd + tolr) {
            for (int q = 0; q < dd; ++q)
                Fn[q] = Ft[q];
            return alpha < 1.0;
        }
        alpha *= 0.5;
    }
    for (int q = 0; q < dd; ++q) /* no decrease found: keep the old F */
        Fn[q] = F[q];
    return 1;
}

/* 3D Neo-Hookean on a block of nb <= BLK elements held as [entry][element] arrays: the
 * unchecked model step of nh_step for all of them in branch-free loops the compiler vectorizes;
 * the elements whose step needs the safeguard (or whose J is outside the fast range of
 * pow_m23_fast) are redone one by one by nh_step, so the results are those of nh_step. */
#define BLK 64
static void nh3_block(long nb, double mu, double kappa, double rho, int rounds,
                      double small_step, double fh[9][BLK], double f0[9][BLK], double fn[9][BLK])
{
    double c[9][BLK], J[BLK], I1[BLK], al[BLK], bb[BLK], beta[BLK];
    int flag[BLK];
    const double mur = mu / rho, kr = kappa / rho, ds = small_step;
    const double lim1 = ds / sqrt(3.0), lim3 = ds * ds * ds;
    for (long i = 0; i < nb; ++i) {
        c[0][i] = f0[4][i] * f0[8][i] - f0[5][i] * f0[7][i];
        c[1][i] = f0[5][i] * f0[6][i] - f0[3][i] * f0[8][i];
        c[2][i] = f0[3][i] * f0[7][i] - f0[4][i] * f0[6][i];
        c[3][i] = f0[7][i] * f0[2][i] - f0[8][i] * f0[1][i];
        c[4][i] = f0[8][i] * f0[0][i] - f0[6][i] * f0[2][i];
        c[5][i] = f0[6][i] * f0[1][i] - f0[7][i] * f0[0][i];
        c[6][i] = f0[1][i] * f0[5][i] - f0[2][i] * f0[4][i];
        c[7][i] = f0[2][i] * f0[3][i] - f0[0][i] * f0[5][i];
        c[8][i] = f0[0][i] * f0[4][i] - f0[1][i] * f0[3][i];
    }
    for (long i = 0; i < nb; ++i) {
        double Ji = f0[0][i] * c[0][i] + f0[1][i] * c[1][i] + f0[2][i] * c[2][i];
        double s = 0.0;
        for (int q = 0; q < 9; ++q)
            s += f0[q][i] * f0[q][i];
        J[i] = Ji;
        I1[i] = s;
        al[i] = ((Ji > 1e-6) & (Ji < 1e6)) ? Ji : 1.0; /* out of range: redone by nh_step */
    }
    for (long i = 0; i < nb; ++i)
        al[i] = pow_m23_fast(al[i]);
    for (long i = 0; i < nb; ++i) {
        double ar = mur * al[i];
        double iJ = 1.0 / J[i];
        bb[i] = kr * J[i] - kr - I1[i] * ar * iJ / 3.0;
        al[i] = ar + 1.0;
        double be = kr * (2.0 - iJ);
        beta[i] = be > 0.0 ? be : 0.0;
    }
    for (long i = 0; i < nb; ++i) {
        double cc = 0.0, cfh = 0.0;
        for (int q = 0; q < 9; ++q) {
            cc += c[q][i] * c[q][i];
            cfh += c[q][i] * fh[q][i];
        }
        double cg = beta[i] * (al[i] * 3.0 * J[i] - cfh + bb[i] * cc) / (al[i] + beta[i] * cc)
                    - bb[i];
        double ial = 1.0 / al[i], dz2 = 0.0;
        for (int q = 0; q < 9; ++q) {
            double v = (fh[q][i] + cg * c[q][i]) * ial;
            double t = v - f0[q][i];
            fn[q][i] = v;
            dz2 += t * t;
        }
        double lim = lim1 * I1[i] + ds * ds * sqrt(I1[i]) + lim3;
        flag[i] = !((J[i] > 1e-6) & (J[i] < 1e6)) | (J[i] <= lim) | (dz2 > ds * ds);
    }
    for (long i = 0; i < nb; ++i) {
        if (!flag[i])
            continue;
        double a0[9], h0[9], out[9];
        for (int q = 0; q < 9; ++q) {
            a0[q] = f0[q][i];
            h0[q] = fh[q][i];
        }
        int again = nh_step(3, a0, h0, out, mu, kappa, rho, small_step);
        for (int round = 1; round < rounds && again; ++round) {
            memcpy(a0, out, sizeof a0);
            again = nh_step(3, a0, h0, out, mu, kappa, rho, small_step);
        }
        for (int q = 0; q < 9; ++q)
            fn[q][i] = out[q];
    }
}

/* any model, any d, one element at a time (2D, linear elasticity) */
static void generic_block(int model, int d, long nb, double mu, double kappa, double rho,
                          double f_dev, double f_vol, int rounds, double small_step,
                          double fh[9][BLK], double f0[9][BLK], double fn[9][BLK])
{
    const int dd = d * d;
    for (long i = 0; i < nb; ++i) {
        double h[MAXD * MAXD], a[MAXD * MAXD], out[MAXD * MAXD];
        for (int q = 0; q < dd; ++q) {
            h[q] = fh[q][i];
            a[q] = f0[q][i];
        }
        if (model == 0) {
            /* closed form on H = F - I: skew + f_dev dev(sym H) + f_vol tr(H)/d I */
            double t = 0.0;
            for (int p = 0; p < d; ++p)
                t += h[p * d + p];
            t = t / d - 1.0;
            for (int p = 0; p < d; ++p)
                for (int q = 0; q < d; ++q) {
                    double sy = 0.5 * (h[p * d + q] + h[q * d + p]);
                    out[p * d + q] = f_dev * sy + (h[p * d + q] - sy);
                }
            for (int p = 0; p < d; ++p)
                out[p * d + p] += (f_vol - f_dev) * t + (1.0 - f_dev);
        } else {
            int again = nh_step(d, a, h, out, mu, kappa, rho, small_step);
            for (int round = 1; round < rounds && again; ++round) {
                memcpy(a, out, sizeof a);
                again = nh_step(d, a, h, out, mu, kappa, rho, small_step);
            }
        }
        for (int q = 0; q < dd; ++q)
            fn[q][i] = out[q];
    }
}

/* one block of elements; d is a compile-time constant at each call site (always inlined), so
 * the gather and scatter loops are fully unrolled */
static inline __attribute__((always_inline)) void iteration_block(
    const int d, int model, long b, long nb, double mu, double kappa, double rho,
    double f_dev, double f_vol, int rounds, double small_step, const int *cells,
    const double *G, const double *wv, const double *h2, const double *u,
    double *F, double *lam, double *r, double *dsq, double *f)
{
    const int dd = d * d, nv = d + 1;
    const long base = b * dd; /* b is a multiple of BLK: the block starts at (b / BLK) dd BLK */
    double fh[9][BLK], f0[9][BLK], fn[9][BLK], l0[9][BLK];
    /* gather: Fhat = I + D_e u + lam */
    for (long i = 0; i < nb; ++i) {
        const long k = b + i;
        const int *cv = cells + k * nv;
        const double *g = G + k * nv * d;
        double H[MAXD * MAXD];
        for (int q = 0; q < dd; ++q)
            H[q] = 0.0;
        for (int a = 0; a < nv; ++a) {
            const double *ua = u + d * cv[a];
            for (int p = 0; p < d; ++p)
                for (int q = 0; q < d; ++q)
                    H[p * d + q] += ua[p] * g[a * d + q];
        }
        for (int p = 0; p < d; ++p)
            H[p * d + p] += 1.0;
        for (int q = 0; q < dd; ++q)
            fh[q][i] = H[q];
    }
    for (int q = 0; q < dd; ++q)
        for (long i = 0; i < nb; ++i) {
            l0[q][i] = lam[base + q * BLK + i];
            fh[q][i] += l0[q][i];
            f0[q][i] = F[base + q * BLK + i];
        }
    /* z-step */
    if (model == 1 && d == 3)
        nh3_block(nb, mu, kappa, rho, rounds, small_step, fh, f0, fn);
    else
        generic_block(model, d, nb, mu, kappa, rho, f_dev, f_vol, rounds, small_step, fh, f0, fn);
    /* dual update, residuals; fh becomes w = F' - lam' (the x-step data) */
    double rr[BLK], zz[BLK];
    for (long i = 0; i < nb; ++i) {
        rr[i] = 0.0;
        zz[i] = 0.0;
    }
    for (int q = 0; q < dd; ++q)
        for (long i = 0; i < nb; ++i) {
            double ln = fh[q][i] - fn[q][i];
            double t = ln - l0[q][i];
            double dz = fn[q][i] - f0[q][i];
            rr[i] += t * t;
            zz[i] += dz * dz;
            F[base + q * BLK + i] = fn[q][i];
            lam[base + q * BLK + i] = ln;
            fh[q][i] = fn[q][i] - ln;
        }
    for (long i = 0; i < nb; ++i) {
        r[b + i] = h2[b + i] * rr[i];
        dsq[b + i] = h2[b + i] * zz[i];
    }
    /* scatter: f_(v_a, p) += W_e sum_q w_pq G_aq */
    for (long i = 0; i < nb; ++i) {
        const long k = b + i;
        const int *cv = cells + k * nv;
        const double *g = G + k * nv * d;
        const double we = wv[k];
        for (int a = 0; a < nv; ++a) {
            double *fa = f + d * cv[a];
            for (int p = 0; p < d; ++p) {
                double s = 0.0;
                for (int q = 0; q < d; ++q)
                    s += fh[p * d + q][i] * g[a * d + q];
                fa[p] += we * s;
            }
        }
    }
}

void admm_iteration(int model, int d, long m, double mu, double kappa, double rho,
                    double f_dev, double f_vol, int rounds, double small_step, const int *cells,
                    const double *G, const double *wv, const double *h2, const double *u,
                    double *F, double *lam, double *r, double *dsq, double *f)
{
    for (long b = 0; b < m; b += BLK) {
        const long nb = m - b < BLK ? m - b : BLK;
        if (d == 3)
            iteration_block(3, model, b, nb, mu, kappa, rho, f_dev, f_vol, rounds, small_step,
                            cells, G, wv, h2, u, F, lam, r, dsq, f);
        else
            iteration_block(2, model, b, nb, mu, kappa, rho, f_dev, f_vol, rounds, small_step,
                            cells, G, wv, h2, u, F, lam, r, dsq, f);
    }
}

/* elements per block of the F and lam layout */
int admm_block_size(void) { return BLK; }

/* ------------------------------------------------------------------------------------------ */
/* The P1 internal forces, the gradient of the elastic energy: f[dofs[e, d a + i]] +=
 * V_e sum_J P_e[i][J] G_e[a][J] over the elements e (in the operators' element order: dofs
 * (m, (d+1) d) node-major dof ids, G (m, d+1, d), V (m)), with F = I + sum_a u_a (x) G_a and P
 * the first Piola stress of mechanics.Law.stress: Neo-Hookean (model 1, seed eq. 14)
 * P = mu J^(-2/3) (F - I1/3 F^-T) + kappa J (J - 1) F^-T, or linear elasticity (model 0)
 * P = 2 mu eps + lambda tr(eps) I. f is accumulated (the caller sets it). Returns the smallest
 * det F over the elements (NaN when one is not a number; 1 for linear elasticity): a value
 * <= 0 is an inverted element, whose (finite, meaningless) forces the caller discards. */
static inline __attribute__((always_inline)) double p1_forces_d(
    const int d, int model, long m, double mu, double kappa, double lmbda, const int *dofs,
    const double *G, const double *V, const double *u, double *f)
{
    const int nv = d + 1, nd = (d + 1) * d;
    double jmin = model == 0 ? 1.0 : INFINITY;
    int nan = 0;
    for (long e = 0; e < m; ++e) {
        const int *de = dofs + e * nd;
        const double *Ge = G + e * nv * d;
        double F[MAXD * MAXD], P[MAXD * MAXD];
        for (int q = 0; q < d * d; ++q)
            F[q] = 0.0;
        for (int a = 0; a < nv; ++a)
            for (int i = 0; i < d; ++i) {
                const double ua = u[de[d * a + i]];
                for (int j = 0; j < d; ++j)
                    F[d * i + j] += ua * Ge[d * a + j];
            }
        if (model == 0) {
            double tr = 0.0;
            for (int i = 0; i < d; ++i)
                tr += F[d * i + i];
            for (int i = 0; i < d; ++i)
                for (int j = 0; j < d; ++j)
                    P[d * i + j] = mu * (F[d * i + j] + F[d * j + i]);
            for (int i = 0; i < d; ++i)
                P[d * i + i] += lmbda * tr;
        } else {
            double cof[MAXD * MAXD], J, I1;
            for (int i = 0; i < d; ++i)
                F[d * i + i] += 1.0;
            parts(d, F, cof, &J, &I1);
            if (J != J)
                nan = 1;
            else if (J < jmin)
                jmin = J;
            const double a = mu * pow_m23(fabs(J));
            const double b = kappa * (J - 1.0) - a * I1 / (3.0 * J);
            for (int q = 0; q < d * d; ++q)
                P[q] = a * F[q] + b * cof[q];
        }
        for (int a = 0; a < nv; ++a)
            for (int i = 0; i < d; ++i) {
                double s = 0.0;
                for (int j = 0; j < d; ++j)
                    s += P[d * i + j] * Ge[d * a + j];
                f[de[d * a + i]] += V[e] * s;
            }
    }
    return nan ? NAN : jmin;
}

double p1_forces(int model, int d, long m, double mu, double kappa, double lmbda,
                 const int *dofs, const double *G, const double *V, const double *u, double *f)
{
    /* d a compile-time constant in each branch: the small loops unroll */
    if (d == 3)
        return p1_forces_d(3, model, m, mu, kappa, lmbda, dofs, G, V, u, f);
    return p1_forces_d(2, model, m, mu, kappa, lmbda, dofs, G, V, u, f);
}

/* ------------------------------------------------------------------------------------------ */
/* The large-mesh x-step: conjugate gradients with a smoothed-aggregation AMG V-cycle on the
 * scalar x-step matrix, k right-hand sides at once (row-major (n, k) arrays: the matrix entries
 * are read once for all k columns). The hierarchy (A, P, R, Jacobi weights per level and the
 * coarsest matrix's direct solve) is built in Python (admm.amg.AmgPcg); this is the
 * arithmetic of amg_array.ArrayAmgPcg's vcycle / pcg, in C. cwork: 3 nc k doubles. The level
 * and coarsest-solve structs (amg_level, amg_coarse) are in admm_kernel.h. */
/* Y = beta Y + alpha M X, M CSR (rows x ?), X and Y row-major with k columns; k is a
 * compile-time constant for k = 2, 3 (unrolled), a loop otherwise */
static inline __attribute__((always_inline)) void csr_mm_k(
    long rows, const int *Mp, const int *Mi, const double *Mx, const int k, const double *X,
    double *Y, double alpha, double beta)
{
    for (long i = 0; i < rows; ++i) {
        double acc[8] = {0.0};
        for (int e = Mp[i]; e < Mp[i + 1]; ++e) {
            const double v = Mx[e];
            const double *xr = X + (long)Mi[e] * k;
            for (int j = 0; j < k; ++j)
                acc[j] += v * xr[j];
        }
        double *y = Y + i * k;
        for (int j = 0; j < k; ++j)
            y[j] = (beta == 0.0 ? 0.0 : beta * y[j]) + alpha * acc[j];
    }
}

/* The coarsest level's direct solve: by the dense inverse of its matrix (Ainv, nc x nc
 * row-major), or, when Ainv is NULL, by its sparse factors Pr A Pc = L U (SuperLU's, CSC: x =
 * Pc U^-1 L^-1 Pr b, with (Pr b)[perm_r[i]] = b[i] and x[i] = w[perm_c[i]]; Ld, Ud their
 * diagonals): the struct amg_coarse in admm_kernel.h.
 * x = A_c^-1 b on k columns; tmp: nc k doubles (the factors' solve) */
static inline __attribute__((always_inline)) void coarse_solve(const amg_coarse *co, const int k,
                                                                const double *b, double *x,
                                                                double *tmp)
{
    const long nc = co->nc;
    if (co->Ainv) {
        for (long i = 0; i < nc; ++i) {
            const double *a = co->Ainv + i * nc;
            double acc[8] = {0.0};
            for (long c = 0; c < nc; ++c)
                for (int j = 0; j < k; ++j)
                    acc[j] += a[c] * b[c * k + j];
            for (int j = 0; j < k; ++j)
                x[i * k + j] = acc[j];
        }
        return;
    }
    double *w = tmp;
    for (long i = 0; i < nc; ++i)
        for (int j = 0; j < k; ++j)
            w[(long)co->perm_r[i] * k + j] = b[i * k + j];
    for (long c = 0; c < nc; ++c) { /* L y = Pr b, column by column */
        double *wc = w + c * k;
        for (int j = 0; j < k; ++j)
            wc[j] /= co->Ld[c];
        for (int e = co->Lp[c]; e < co->Lp[c + 1]; ++e) {
            const long i = co->Li[e];
            if (i > c)
                for (int j = 0; j < k; ++j)
                    w[i * k + j] -= co->Lx[e] * wc[j];
        }
    }
    for (long c = nc - 1; c >= 0; --c) { /* U w = y */
        double *wc = w + c * k;
        for (int j = 0; j < k; ++j)
            wc[j] /= co->Ud[c];
        for (int e = co->Up[c]; e < co->Up[c + 1]; ++e) {
            const long i = co->Ui[e];
            if (i < c)
                for (int j = 0; j < k; ++j)
                    w[i * k + j] -= co->Ux[e] * wc[j];
        }
    }
    for (long i = 0; i < nc; ++i)
        for (int j = 0; j < k; ++j)
            x[i * k + j] = w[(long)co->perm_c[i] * k + j];
}

/* x = V(b): one pre- and one post-smoothing damped-Jacobi sweep per level (down: x_l = dw b_l,
 * r_l = b_l - A_l x_l, b_(l+1) = R_l r_l; coarsest: x = Ainv b; up: x_l += P_l x_(l+1),
 * x_l += dw (b_l - A_l x_l)) */
static inline __attribute__((always_inline)) void vcycle(
    int nlev, const amg_level *lv, const amg_coarse *co, const int k, const double *b0,
    double *x0, double *cwork)
{
    const long nc = co->nc;
    for (int l = 0; l < nlev; ++l) {
        const amg_level *L = lv + l;
        const double *b = l ? L->b : b0;
        double *x = l ? L->x : x0, *r = L->r;
        const long n = L->n;
        double *bn = (l + 1 < nlev) ? lv[l + 1].b : cwork;
        const long nn = (l + 1 < nlev) ? lv[l + 1].n : nc;
        for (long i = 0; i < n; ++i)
            for (int j = 0; j < k; ++j) {
                x[i * k + j] = L->dw[i] * b[i * k + j];
                r[i * k + j] = b[i * k + j];
            }
        csr_mm_k(n, L->Ap, L->Ai, L->Ax, k, x, r, -1.0, 1.0);
        csr_mm_k(nn, L->Rp, L->Ri, L->Rx, k, r, bn, 1.0, 0.0);
    }
    if (nlev == 0) { /* no levels: the coarsest matrix is the matrix */
        coarse_solve(co, k, b0, x0, cwork + 2 * nc * k);
        return;
    }
    coarse_solve(co, k, cwork, cwork + nc * k, cwork + 2 * nc * k);
    for (int l = nlev - 1; l >= 0; --l) {
        const amg_level *L = lv + l;
        const double *b = l ? L->b : b0;
        double *x = l ? L->x : x0, *r = L->r;
        const long n = L->n;
        const double *xn = (l + 1 < nlev) ? lv[l + 1].x : cwork + nc * k;
        csr_mm_k(n, L->Pp, L->Pi, L->Px, k, xn, x, 1.0, 1.0);
        for (long t = 0; t < n * k; ++t)
            r[t] = b[t];
        csr_mm_k(n, L->Ap, L->Ai, L->Ax, k, x, r, -1.0, 1.0);
        for (long i = 0; i < n; ++i)
            for (int j = 0; j < k; ++j)
                x[i * k + j] += L->dw[i] * r[i * k + j];
    }
}

/* PCG from X (in place) on A X = B (level 0's A), k <= 8 columns; stops after maxit iterations,
 * when every column's residual is below rtol |B_j|, or (step_tol > 0) after at least min_it
 * iterations once the largest row update is below max(step_tol, step_rtol x the first one).
 * work: 4 n k doubles; cwork: 3 nc k. Returns the iterations done; *last_update = the largest
 * row update (2-norm over the k columns) of the last iteration. */
static inline __attribute__((always_inline)) int pcg_k(
    int nlev, const amg_level *lv, const amg_coarse *co, const int k, const double *B,
    double *X, int maxit, double rtol, double step_tol, double step_rtol, int min_it,
    double *work, double *cwork, double *last_update)
{
    const long n = lv[0].n, nk = n * k;
    double *r = work, *z = work + nk, *p = work + 2 * nk, *Ap = work + 3 * nk;
    double rz[8], stop[8], alpha[8], lim = 0.0, dmax = 0.0;
    for (int j = 0; j < k; ++j) {
        double s = 0.0;
        for (long i = 0; i < n; ++i)
            s += B[i * k + j] * B[i * k + j];
        stop[j] = rtol * sqrt(s);
    }
    for (long t = 0; t < nk; ++t)
        r[t] = B[t];
    csr_mm_k(n, lv[0].Ap, lv[0].Ai, lv[0].Ax, k, X, r, -1.0, 1.0);
    vcycle(nlev, lv, co, k, r, z, cwork);
    for (long t = 0; t < nk; ++t)
        p[t] = z[t];
    for (int j = 0; j < k; ++j) {
        double s = 0.0;
        for (long i = 0; i < n; ++i)
            s += r[i * k + j] * z[i * k + j];
        rz[j] = s;
    }
    int it;
    for (it = 0; it < maxit; ++it) {
        csr_mm_k(n, lv[0].Ap, lv[0].Ai, lv[0].Ax, k, p, Ap, 1.0, 0.0);
        for (int j = 0; j < k; ++j) {
            double s = 0.0;
            for (long i = 0; i < n; ++i)
                s += p[i * k + j] * Ap[i * k + j];
            alpha[j] = s > 0.0 ? rz[j] / s : 0.0;
        }
        dmax = 0.0;
        for (long i = 0; i < n; ++i) {
            double d2 = 0.0;
            for (int j = 0; j < k; ++j) {
                double dx = alpha[j] * p[i * k + j];
                X[i * k + j] += dx;
                r[i * k + j] -= alpha[j] * Ap[i * k + j];
                d2 += dx * dx;
            }
            if (d2 > dmax)
                dmax = d2;
        }
        if (it == maxit - 1)
            break;
        int done = 1;
        for (int j = 0; j < k; ++j) {
            double s = 0.0;
            for (long i = 0; i < n; ++i)
                s += r[i * k + j] * r[i * k + j];
            if (!(sqrt(s) <= stop[j]))
                done = 0;
        }
        if (done)
            break;
        if (step_tol > 0.0) {
            if (it == 0)
                lim = fmax(step_tol * step_tol, step_rtol * step_rtol * dmax);
            if (it + 1 >= min_it && dmax <= lim)
                break;
        }
        vcycle(nlev, lv, co, k, r, z, cwork);
        for (int j = 0; j < k; ++j) {
            double s = 0.0;
            for (long i = 0; i < n; ++i)
                s += r[i * k + j] * z[i * k + j];
            double beta = rz[j] > 0.0 ? s / rz[j] : 0.0;
            rz[j] = s;
            for (long i = 0; i < n; ++i)
                p[i * k + j] = z[i * k + j] + beta * p[i * k + j];
        }
    }
    *last_update = sqrt(dmax);
    return it + 1;
}

/* X = V(B): one V-cycle on k columns (the preconditioner alone, for an iteration run elsewhere);
 * cwork: 3 nc k doubles */
void amg_vcycle(int nlev, const amg_level *lv, const amg_coarse *co, int k, const double *B,
                double *X, double *cwork)
{
    if (k == 3)
        vcycle(nlev, lv, co, 3, B, X, cwork);
    else if (k == 2)
        vcycle(nlev, lv, co, 2, B, X, cwork);
    else
        vcycle(nlev, lv, co, k, B, X, cwork);
}

int amg_pcg(int nlev, const amg_level *lv, const amg_coarse *co, int k, const double *B,
            double *X, int maxit, double rtol, double step_tol, double step_rtol, int min_it,
            double *work, double *cwork, double *last_update)
{
    if (k == 3)
        return pcg_k(nlev, lv, co, 3, B, X, maxit, rtol, step_tol, step_rtol, min_it, work, cwork,
                     last_update);
    if (k == 2)
        return pcg_k(nlev, lv, co, 2, B, X, maxit, rtol, step_tol, step_rtol, min_it, work, cwork,
                     last_update);
    return pcg_k(nlev, lv, co, k, B, X, maxit, rtol, step_tol, step_rtol, min_it, work, cwork,
                 last_update);
}

/* ------------------------------------------------------------------------------------------ */
/* The Mass Tensor method's "amg" iteration (solvers/mass_tensor/iterations.py, solve_linear):
 * conjugate gradients on P K P for the displacement u = u_c + P w, preconditioned by one V-cycle
 * per displacement component of the scalar hierarchy on the vertices not fully held. K: the
 * tensors as CSR on node-major dofs (n d rows); P (n, d, d) the projectors onto each vertex's
 * free directions; free (nf): the V-cycle's vertices, in its row order. u (n d): in, the start
 * (its prescribed part already set); out, the last iterate. f (n d): the external forces (mN).
 *
 * Each iteration appends its largest per-vertex move to steps (mm) and stops once the distance
 * still to go, estimated as s rho / (1 - rho) from the last move s and the largest contraction
 * rho of the last `tail` moves, is below margin x stop_mm, or a move is exactly zero.
 * Returns: 0 stopped by that rule, 1 max_it iterations done, 2 a non-positive preconditioned
 * residual (info[0] = r.z), 3 non-positive curvature (info[0] = p.Kp), 4 a vertex moved a
 * non-finite distance or more than blowup mm (*bad = the vertex, info[0] = its move), 5 the
 * largest residual grew past 1e12 x its first value or is not finite (info[0] = it). *n_it: the
 * moves made and recorded in steps (for 3 and 4, the failing iteration's is not one of them).
 * work: 4 n d + 2 nf d doubles; cwork: 3 nc d. */
static inline __attribute__((always_inline)) void mt_project(long n, const int d, const double *P,
                                                              const double *x, double *y)
{
    for (long i = 0; i < n; ++i) {
        const double *Pi = P + i * d * d, *xi = x + i * d;
        double yi[MAXD];
        for (int a = 0; a < d; ++a) {
            double s = 0.0;
            for (int b = 0; b < d; ++b)
                s += Pi[a * d + b] * xi[b];
            yi[a] = s;
        }
        for (int a = 0; a < d; ++a)
            y[i * d + a] = yi[a];
    }
}

static inline __attribute__((always_inline)) void mt_precondition(
    long n, const int d, const double *P, long nf, const int *free, int nlev, const amg_level *lv,
    const amg_coarse *co, const double *r, double *z, double *bf, double *xf, double *cwork)
{
    memset(z, 0, sizeof(double) * n * d);
    if (nf == 0)
        return;
    for (long t = 0; t < nf; ++t)
        for (int a = 0; a < d; ++a)
            bf[t * d + a] = r[(long)free[t] * d + a];
    vcycle(nlev, lv, co, d, bf, xf, cwork);
    for (long t = 0; t < nf; ++t) {
        const long i = free[t];
        const double *Pi = P + i * d * d;
        for (int a = 0; a < d; ++a) {
            double s = 0.0;
            for (int b = 0; b < d; ++b)
                s += Pi[a * d + b] * xf[t * d + b];
            z[i * d + a] = s;
        }
    }
}

/* the larger of a and b, NaN when either is (numpy's max, unlike fmax) */
static inline double max_nan(double a, double b)
{
    return (isnan(a) || a > b) ? a : b;
}

static inline double dot(long m, const double *x, const double *y)
{
    double s = 0.0;
    for (long t = 0; t < m; ++t)
        s += x[t] * y[t];
    return s;
}

static inline __attribute__((always_inline)) int mt_pcg_d(
    long n, const int d, const int *Kp, const int *Ki, const double *Kx, const double *P, long nf,
    const int *free, int nlev, const amg_level *lv, const amg_coarse *co, const double *f,
    double *u, int max_it, double stop_mm, int tail, double margin, double blowup,
    double *steps, int *n_it, int *bad, double *info, double *work, double *cwork)
{
    const long nd = n * d;
    double *r = work, *z = work + nd, *p = work + 2 * nd, *q = work + 3 * nd;
    double *bf = work + 4 * nd, *xf = bf + nf * d;
    *n_it = 0;
    csr_mm_k(nd, Kp, Ki, Kx, 1, u, q, 1.0, 0.0); /* r = P (f - K u) */
    for (long t = 0; t < nd; ++t)
        q[t] = f[t] - q[t];
    mt_project(n, d, P, q, r);
    mt_precondition(n, d, P, nf, free, nlev, lv, co, r, z, bf, xf, cwork);
    memcpy(p, z, sizeof(double) * nd);
    double rz = dot(nd, r, z), r0 = 0.0;
    for (long t = 0; t < nd; ++t)
        r0 = max_nan(r0, fabs(r[t]));
    r0 = max_nan(r0, 1e-300);
    int it = 0;
    while (it < max_it) {
        if (rz <= 0.0) {
            if (rz == 0.0)
                break;
            info[0] = rz;
            *n_it = it;
            return 2;
        }
        ++it;
        csr_mm_k(nd, Kp, Ki, Kx, 1, p, z, 1.0, 0.0); /* q = P K p (z: scratch) */
        mt_project(n, d, P, z, q);
        const double pq = dot(nd, p, q);
        if (!(pq > 0.0)) {
            info[0] = pq;
            *n_it = it - 1; /* moves made; this iteration made none */
            return 3;
        }
        const double alpha = rz / pq;
        long worst = 0, first_bad = -1;
        double smax = -1.0, bad_move = 0.0;
        for (long i = 0; i < n; ++i) {
            double s2 = 0.0;
            for (int a = 0; a < d; ++a) {
                const double dx = alpha * p[i * d + a];
                u[i * d + a] += dx;
                s2 += dx * dx;
            }
            const double s = sqrt(s2);
            if (!isfinite(s) && first_bad < 0) {
                first_bad = i;
                bad_move = s;
            }
            if (s > smax) {
                smax = s;
                worst = i;
            }
        }
        if (n == 0)
            smax = 0.0;
        steps[it - 1] = smax;
        if (first_bad >= 0 || smax > blowup) {
            *bad = (int)(first_bad >= 0 ? first_bad : worst);
            info[0] = first_bad >= 0 ? bad_move : smax;
            *n_it = it - 1; /* this move is refused, not recorded */
            return 4;
        }
        double rmax = 0.0;
        for (long t = 0; t < nd; ++t) {
            r[t] -= alpha * q[t];
            rmax = max_nan(rmax, fabs(r[t]));
        }
        if (!isfinite(rmax) || rmax > 1e12 * r0) {
            info[0] = rmax;
            *n_it = it;
            return 5;
        }
        if (smax == 0.0)
            break;
        if (it > tail) { /* the distance still to go */
            double rho = 0.0;
            for (int t = it - tail; t < it; ++t) {
                const double ratio = steps[t] / steps[t - 1];
                rho = (ratio > rho || isnan(ratio)) ? ratio : rho;
            }
            if (rho < 1.0 && steps[it - 1] * rho / (1.0 - rho) / margin < stop_mm)
                break;
        }
        mt_precondition(n, d, P, nf, free, nlev, lv, co, r, z, bf, xf, cwork);
        const double rz_new = dot(nd, r, z);
        const double beta = rz_new / rz;
        for (long t = 0; t < nd; ++t)
            p[t] = z[t] + beta * p[t];
        rz = rz_new;
    }
    *n_it = it;
    return it >= max_it ? 1 : 0;
}

int mt_amg_pcg(long n, int d, const int *Kp, const int *Ki, const double *Kx, const double *P,
               long nf, const int *free, int nlev, const amg_level *lv, const amg_coarse *co,
               const double *f, double *u, int max_it, double stop_mm, int tail, double margin,
               double blowup, double *steps, int *n_it, int *bad, double *info, double *work,
               double *cwork)
{
    if (d == 3)
        return mt_pcg_d(n, 3, Kp, Ki, Kx, P, nf, free, nlev, lv, co, f, u, max_it, stop_mm, tail,
                        margin, blowup, steps, n_it, bad, info, work, cwork);
    return mt_pcg_d(n, 2, Kp, Ki, Kx, P, nf, free, nlev, lv, co, f, u, max_it, stop_mm, tail,
                    margin, blowup, steps, n_it, bad, info, work, cwork);
}

/* ------------------------------------------------------------------------------------------ */
/* The Mass Tensor method's tensors (solvers/mass_tensor/tensors.py, stiffness_tensors): per
 * cell its barycentric gradients g_a (the cofactors of the edge matrix over its determinant;
 * 1/mm) and measure V, and the products O_ab = V g_a g_b^T summed per vertex (S_ii, (n, d, d),
 * a = b) and per edge (S_e, (2 e, d, d): pair k of cell c at slot pair_edge[c p + k], plus e
 * when the pair's first vertex is its edge's second), in cell order (numpy's bincount order).
 * The caller zeroes S_ii and S_e. Returns -1, or the first cell of zero measure (nothing summed
 * past it). */
long mt_tensor_sums(int d, long m, const int64_t *cells, const double *points,
                    const int64_t *pair_edge, const uint8_t *flipped, long e, double *S_ii,
                    double *S_e)
{
    const int nv = d + 1, np_ = nv * d / 2;
    for (long c = 0; c < m; ++c) {
        const int64_t *cv = cells + c * nv;
        const double *x0 = points + cv[0] * d;
        double E[MAXD][MAXD], g[MAXD + 1][MAXD], det, vol;
        for (int k = 0; k < d; ++k)
            for (int j = 0; j < d; ++j)
                E[k][j] = points[cv[k + 1] * d + j] - x0[j];
        if (d == 3) {
            double cof[3][3];
            for (int k = 0; k < 3; ++k) { /* e_(k+1) x e_(k+2) */
                const double *a = E[(k + 1) % 3], *b = E[(k + 2) % 3];
                cof[k][0] = a[1] * b[2] - a[2] * b[1];
                cof[k][1] = a[2] * b[0] - a[0] * b[2];
                cof[k][2] = a[0] * b[1] - a[1] * b[0];
            }
            det = E[0][0] * cof[0][0] + E[0][1] * cof[0][1] + E[0][2] * cof[0][2];
            if (!(fabs(det) > 0.0))
                return c;
            for (int k = 0; k < 3; ++k)
                for (int j = 0; j < 3; ++j)
                    g[k + 1][j] = cof[k][j] / det;
            vol = fabs(det) / 6.0;
        } else {
            det = E[0][0] * E[1][1] - E[0][1] * E[1][0];
            if (!(fabs(det) > 0.0))
                return c;
            g[1][0] = E[1][1] / det; /* the columns of E^-1 */
            g[1][1] = -E[1][0] / det;
            g[2][0] = -E[0][1] / det;
            g[2][1] = E[0][0] / det;
            vol = fabs(det) / 2.0;
        }
        const double sv = sqrt(vol);
        for (int j = 0; j < d; ++j) {
            double s = 0.0;
            for (int k = 1; k < nv; ++k)
                s += g[k][j];
            g[0][j] = -s;
        }
        for (int a = 0; a < nv; ++a)
            for (int j = 0; j < d; ++j)
                g[a][j] *= sv;
        for (int a = 0; a < nv; ++a) {
            double *S = S_ii + cv[a] * d * d;
            for (int i = 0; i < d; ++i)
                for (int j = 0; j < d; ++j)
                    S[i * d + j] += g[a][i] * g[a][j];
        }
        int k = 0;
        for (int a = 0; a < nv; ++a)
            for (int b = a + 1; b < nv; ++b, ++k) {
                const long slot = pair_edge[c * np_ + k] + (flipped[c * np_ + k] ? e : 0);
                double *S = S_e + slot * d * d;
                for (int i = 0; i < d; ++i)
                    for (int j = 0; j < d; ++j)
                        S[i * d + j] += g[a][i] * g[b][j];
            }
    }
    return -1;
}

/* ------------------------------------------------------------------------------------------ */
/* The AMG hierarchy's aggregation (solvers/admm/amg.py, strength_aggregates), compiled: on the
 * graph of the strength matrix S (CSR, n rows), roots whose neighbourhood is still free, then
 * the leftovers joined to a neighbouring aggregate of the first pass, then isolated ones; the
 * same greedy order, so the same aggregates. first: n scratch. Returns the number of
 * aggregates; agg (n) the aggregate of each row. */
long amg_aggregates(long n, const int *Sp, const int *Si, int64_t *agg, int64_t *first)
{
    long na = 0;
    for (long i = 0; i < n; ++i)
        agg[i] = -1;
    for (long i = 0; i < n; ++i) {
        if (agg[i] >= 0)
            continue;
        int free_ = 1;
        for (int e = Sp[i]; e < Sp[i + 1]; ++e)
            if (agg[Si[e]] >= 0) {
                free_ = 0;
                break;
            }
        if (free_) {
            for (int e = Sp[i]; e < Sp[i + 1]; ++e)
                agg[Si[e]] = na;
            agg[i] = na;
            ++na;
        }
    }
    for (long i = 0; i < n; ++i)
        first[i] = agg[i];
    for (long i = 0; i < n; ++i)
        if (first[i] < 0)
            for (int e = Sp[i]; e < Sp[i + 1]; ++e)
                if (first[Si[e]] >= 0) {
                    agg[i] = first[Si[e]];
                    break;
                }
    for (long i = 0; i < n; ++i)
        if (agg[i] < 0)
            agg[i] = na++;
    return na;
}
