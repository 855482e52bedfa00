/* The declarations the fast solvers' compiled kernel (admm_kernel.c) exports: the structs and
 * functions it shares with Python. solvers/ckernel.py hands this file to cffi as the interface
 * (so it holds no preprocessor lines) and admm_kernel.c includes it, so the compiler checks the
 * definitions against it. Integer types from <stdint.h>, included first by admm_kernel.c. */
void admm_iteration(int model, int d, long m, double mu, double kappa, double rho,
                    double f_dev, double f_vol, int rounds, double small_step, const int *cells,
                    const double *G, const double *wv, const double *h2, const double *u,
                    double *F, double *lam, double *r, double *dsq, double *f);
int admm_block_size(void);
double p1_forces(int model, int d, long m, double mu, double kappa, double lmbda,
                 const int *dofs, const double *G, const double *V, const double *u, double *f);
/* one level of an AMG hierarchy (CSR arrays), k columns of scratch */
typedef struct {
    long n;
    const int *Ap, *Ai;
    const double *Ax;
    const int *Pp, *Pi; /* n x (next level's n) */
    const double *Px;
    const int *Rp, *Ri; /* (next level's n) x n */
    const double *Rx;
    const double *dw; /* damped-Jacobi weights (n) */
    double *x, *r, *b; /* scratch, n * k each */
} amg_level;
/* the coarsest level's direct solve (see coarse_solve in admm_kernel.c) */
typedef struct {
    long nc;
    const double *Ainv;
    const int *Lp, *Li;
    const double *Lx, *Ld;
    const int *Up, *Ui;
    const double *Ux, *Ud;
    const int *perm_r, *perm_c;
} amg_coarse;
int amg_pcg(int nlev, const amg_level *lv, const amg_coarse *co, int k, const double *B,
            double *X, int maxit, double rtol, double step_tol, double step_rtol, int min_it,
            double *work, double *cwork, double *last_update);
void amg_vcycle(int nlev, const amg_level *lv, const amg_coarse *co, int k, const double *B,
                double *X, double *cwork);
int mt_amg_pcg(long n, int d, const int *Kp, const int *Ki, const double *Kx, const double *P,
               long nf, const int *free, int nlev, const amg_level *lv, const amg_coarse *co,
               const double *f, double *u, int max_it, double stop_mm, int tail, double margin,
               double blowup, double *steps, int *n_it, int *bad, double *info, double *work,
               double *cwork);
long mt_tensor_sums(int d, long m, const int64_t *cells, const double *points,
                    const int64_t *pair_edge, const uint8_t *flipped, long e, double *S_ii,
                    double *S_e);
long amg_aggregates(long n, const int *Sp, const int *Si, int64_t *agg, int64_t *first);
