/* One ADMM iteration's element work for solvers/admm.py, compiled: for every element, the
 * gradient of the x-step's displacement (gather), the z-step, the dual update, the residuals, and
 * the element's share of the next x-step's right-hand side (scatter), in one pass over memory.
 *
 * The same arithmetic as the numpy loop of admm._admm / admm._ZStep: F = I + z,
 * Fhat = I + D u + lam; the Neo-Hookean z-step is the safeguarded model-Newton step of
 * _ZStep._step (up to `rounds` rounds for the elements whose step the line search shortened),
 * the linear-elastic one its closed form. Element arrays are structure-of-arrays blocks (d, d, m):
 * entry (i, J) of element k at (d i + J) m + k; cells (m, d+1) and G (m, d+1, d) (shape-function
 * gradients, 1/mm) in the same (internal) element order; u and f node-major (d v + i).
 *
 * Outputs per element k: Fn (new F), lam_new = Fhat - Fn, r[k] = h2[k] |lam_new - lam|^2
 * (primal residual squared, mm^2), dsq[k] = h2[k] |Fn - F|^2 (dual residual squared at rho0,
 * mm^2), and f += W_e D_e^T (Fn - lam_new) with W_e = wv[k] (rho0 V_e): f is D^T W (z - lam),
 * the x-step's data term (f is accumulated, the caller zeroes it).
 *
 * model: 0 linear elasticity (closed form, f_dev, f_vol), 1 Neo-Hookean (seed eq. 14), plane
 * strain in 2D. Units: mu, kappa, rho in kPa.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

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
    const int d, int model, long m, long b, long nb, double mu, double kappa, double rho,
    double f_dev, double f_vol, int rounds, double small_step, const long *cells,
    const double *G, const double *wv, const double *h2, const double *u, const double *lam,
    const double *F, double *Fn, double *lam_new, double *r, double *dsq, double *f)
{
    const int dd = d * d, nv = d + 1;
    double fh[9][BLK], f0[9][BLK], fn[9][BLK], l0[9][BLK];
    /* gather: Fhat = I + D_e u + lam */
    for (long i = 0; i < nb; ++i) {
        const long k = b + i;
        const long *cv = cells + k * nv;
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
            l0[q][i] = lam[q * m + b + i];
            fh[q][i] += l0[q][i];
            f0[q][i] = F[q * m + b + i];
        }
    /* z-step */
    if (model == 1 && d == 3)
        nh3_block(nb, mu, kappa, rho, rounds, small_step, fh, f0, fn);
    else
        generic_block(model, d, nb, mu, kappa, rho, f_dev, f_vol, rounds, small_step, fh, f0, fn);
    /* dual update, residuals; fh becomes w = Fn - lam_new (the x-step data) */
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
            Fn[q * m + b + i] = fn[q][i];
            lam_new[q * m + b + i] = ln;
            fh[q][i] = fn[q][i] - ln;
        }
    for (long i = 0; i < nb; ++i) {
        r[b + i] = h2[b + i] * rr[i];
        dsq[b + i] = h2[b + i] * zz[i];
    }
    /* scatter: f_(v_a, p) += W_e sum_q w_pq G_aq */
    for (long i = 0; i < nb; ++i) {
        const long k = b + i;
        const long *cv = cells + k * nv;
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
                    double f_dev, double f_vol, int rounds, double small_step, const long *cells,
                    const double *G, const double *wv, const double *h2, const double *u,
                    const double *lam, const double *F, double *Fn, double *lam_new, double *r,
                    double *dsq, double *f)
{
    for (long b = 0; b < m; b += BLK) {
        const long nb = m - b < BLK ? m - b : BLK;
        if (d == 3)
            iteration_block(3, model, m, b, nb, mu, kappa, rho, f_dev, f_vol, rounds, small_step,
                            cells, G, wv, h2, u, lam, F, Fn, lam_new, r, dsq, f);
        else
            iteration_block(2, model, m, b, nb, mu, kappa, rho, f_dev, f_vol, rounds, small_step,
                            cells, G, wv, h2, u, lam, F, Fn, lam_new, r, dsq, f);
    }
}
