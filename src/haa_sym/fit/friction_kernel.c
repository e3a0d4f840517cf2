/* The friction simulation of haa_sym.fit.friction: the recursion over grid intervals and substeps.
 *
 * Per substep of interval k (length h_k, n_sub[k] substeps, the matrices of that length):
 *   px = P x,  a = px + G[:, :m] u,   x+ = a + H T,   H = G[:, m:],
 *   T_b = -Fc_b tanh(x+[c_b] / v_s)            (implicit in T: nf equations, Newton).
 * Sensitivities, per key j, in the shifted variable sigma_j = s_j + X_j x (X_j the solution of
 * A X - X A = dA_j off A's eigenbasis diagonal, Dd_j its diagonal part: then
 * d e^{A h} = e^{A h} X - X e^{A h} + h e^{A h} Dd, and the same for its integral), exact:
 *   v   = h px + Gs ut                           (ut = [u; T]; Gs = int_0^h s e^{A s} ds [B, W]),
 *   pre = P sigma + Dd_j v + GY_j ut  (+ dl_k (A x+ + BW ut) for the delay's key),
 *   r_c = pre[c] - (X_j x+)[c],   (I - Dg M) dT = Dg r_c + q,   sigma+ = pre + H dT,
 * with M = H[c, :], Dg = diag(-Fc/v_s sech^2(v/v_s)), q_b = -tanh(v_b/v_s) when key j is Fc_b;
 * dl_k: the substep's length's derivative along the delay; kterms[j] = 0: Dd_j and GY_j are 0.
 * Layouts are C order: P (K, n, n), G, Gs (K, n, mw), GY (np, K, n, mw), Dd, Xk (np, n, n),
 * A (n, n), BW (n, mw), u (K, m), X (K + 1, n), S (np, K + 1, n); mw = m + nf. Returns 0, or 1
 * when a Newton solve did not converge (the caller refuses the point). */
#include <math.h>
#include <string.h>

#define NFMAX 8

/* solve the nf x nf system A z = b in place (Gaussian elimination, partial pivoting) */
static int solve_small(int nf, double *A, double *b)
{
    for (int c = 0; c < nf; ++c) {
        int piv = c;
        for (int r = c + 1; r < nf; ++r)
            if (fabs(A[r * nf + c]) > fabs(A[piv * nf + c])) piv = r;
        if (A[piv * nf + c] == 0.0) return 1;
        if (piv != c) {
            for (int k = 0; k < nf; ++k) { double t = A[c * nf + k]; A[c * nf + k] = A[piv * nf + k]; A[piv * nf + k] = t; }
            double t = b[c]; b[c] = b[piv]; b[piv] = t;
        }
        for (int r = c + 1; r < nf; ++r) {
            double f = A[r * nf + c] / A[c * nf + c];
            for (int k = c; k < nf; ++k) A[r * nf + k] -= f * A[c * nf + k];
            b[r] -= f * b[c];
        }
    }
    for (int c = nf - 1; c >= 0; --c) {
        double acc = b[c];
        for (int k = c + 1; k < nf; ++k) acc -= A[c * nf + k] * b[k];
        b[c] = acc / A[c * nf + c];
    }
    return 0;
}

int haa_fit_friction(int K, int n, int m, int nf, int np_, const int *nsub, const double *hs,
                     const double *P, const double *G, const double *Gs, const double *GY,
                     const double *Dd, const double *Xk, const double *A, const double *BW,
                     const double *dl, int dkey, const int *kterms,
                     const double *u, const int *csel, const double *Fc, double vs,
                     const int *fck, const double *x0, const double *s0, int sens,
                     double *X, double *S, double *work)
{
    const int mw = m + nf;
    double *a = work, *xn = work + n, *px = work + 2 * n, *v = work + 3 * n, *pre = work + 4 * n;  /* 5 n */
    double T[NFMAX], F[NFMAX], Jm[NFMAX * NFMAX], dT[NFMAX], Dg[NFMAX], th[NFMAX], ut[64];
    int fail = 0;
    double scale = 0.0;
    for (int b = 0; b < nf; ++b) scale += Fc[b];
    if (!(scale > 0)) scale = 1.0;
    if (mw > 64) return 1;
    memcpy(X, x0, sizeof(double) * n);
    if (sens)
        for (int j = 0; j < np_; ++j) memcpy(S + (size_t)j * (K + 1) * n, s0 + (size_t)j * n, sizeof(double) * n);
    for (int b = 0; b < nf; ++b) T[b] = 0.0;
    for (int k = 0; k < K; ++k) {
        const double *Pk = P + (size_t)k * n * n, *Gk = G + (size_t)k * n * mw, *uk = u + (size_t)k * m;
        const double *Gsk = Gs + (size_t)k * n * mw;
        const double h = hs[k];
        double *xk = X + (size_t)(k + 1) * n;
        memcpy(xk, X + (size_t)k * n, sizeof(double) * n);
        if (sens)
            for (int j = 0; j < np_; ++j) {
                double *Sj = S + (size_t)j * (K + 1) * n;
                memcpy(Sj + (size_t)(k + 1) * n, Sj + (size_t)k * n, sizeof(double) * n);
            }
        for (int l = 0; l < m; ++l) ut[l] = uk[l];
        for (int sub = 0; sub < nsub[k]; ++sub) {
            for (int i = 0; i < n; ++i) {
                double acc = 0.0, acu = 0.0;
                for (int l = 0; l < n; ++l) acc += Pk[i * n + l] * xk[l];
                for (int l = 0; l < m; ++l) acu += Gk[i * mw + l] * uk[l];
                px[i] = acc;
                a[i] = acc + acu;
            }
            /* Newton on F(T) = T + Fc tanh((a_c + M T) / vs) = 0: each F_b rises with T_b
             * (M's diagonal h/J > 0), the root is unique in [-Fc, Fc] */
            int it;
            double norm = 0.0;
            for (int b = 0; b < nf; ++b) {
                double acc = a[csel[b]];
                for (int c = 0; c < nf; ++c) acc += Gk[csel[b] * mw + m + c] * T[c];
                th[b] = tanh(acc / vs);
                F[b] = T[b] + Fc[b] * th[b];
                norm += fabs(F[b]);
            }
            for (it = 0; it < 100; ++it) {
                if (norm <= 1e-15 * scale) break;
                for (int b = 0; b < nf; ++b) {
                    double sl = Fc[b] / vs * (1.0 - th[b] * th[b]);
                    for (int c = 0; c < nf; ++c) Jm[b * nf + c] = (b == c) + sl * Gk[csel[b] * mw + m + c];
                    dT[b] = -F[b];
                }
                if (solve_small(nf, Jm, dT)) { fail = 1; break; }
                /* the step is halved until |F| falls; the residual and tanh at the accepted point
                 * are the next iteration's */
                double lam = 1.0, T1[NFMAX], th1[NFMAX], F1[NFMAX], n1 = 0.0;
                for (int tries = 0; tries < 60; ++tries, lam *= 0.5) {
                    n1 = 0.0;
                    for (int b = 0; b < nf; ++b) T1[b] = T[b] + lam * dT[b];
                    for (int b = 0; b < nf; ++b) {
                        double acc = a[csel[b]];
                        for (int c = 0; c < nf; ++c) acc += Gk[csel[b] * mw + m + c] * T1[c];
                        th1[b] = tanh(acc / vs);
                        F1[b] = T1[b] + Fc[b] * th1[b];
                        n1 += fabs(F1[b]);
                    }
                    if (n1 < norm || tries == 59) break;
                }
                double moved = 0.0;
                for (int b = 0; b < nf; ++b) {
                    moved += fabs(T1[b] - T[b]);
                    T[b] = T1[b]; th[b] = th1[b]; F[b] = F1[b];
                }
                norm = n1;
                if (moved <= 1e-16 * scale) break;
            }
            if (it == 100) fail = 1;
            for (int b = 0; b < nf; ++b) {
                double acc = a[csel[b]];
                for (int c = 0; c < nf; ++c) acc += Gk[csel[b] * mw + m + c] * T[c];
                th[b] = tanh(acc / vs);
                T[b] = -Fc[b] * th[b];
                Dg[b] = -Fc[b] / vs * (1.0 - th[b] * th[b]);
                ut[m + b] = T[b];
            }
            for (int i = 0; i < n; ++i) {
                double acc = a[i];
                for (int c = 0; c < nf; ++c) acc += Gk[i * mw + m + c] * T[c];
                xn[i] = acc;
            }
            if (sens) {
                for (int i = 0; i < n; ++i) {
                    double acc = h * px[i];
                    for (int l = 0; l < mw; ++l) acc += Gsk[i * mw + l] * ut[l];
                    v[i] = acc;
                }
                for (int j = 0; j < np_; ++j) {
                    double *sj = S + (size_t)j * (K + 1) * n + (size_t)(k + 1) * n;
                    const double *Ddj = Dd + (size_t)j * n * n, *Xj = Xk + (size_t)j * n * n;
                    const double *GYk = GY + ((size_t)j * K + k) * n * mw;
                    for (int i = 0; i < n; ++i) {
                        double acc = 0.0;
                        for (int l = 0; l < n; ++l) acc += Pk[i * n + l] * sj[l];
                        if (kterms[j]) {      /* a key of A, B or W (not a friction torque, the delay) */
                            for (int l = 0; l < n; ++l) acc += Ddj[i * n + l] * v[l];
                            for (int l = 0; l < mw; ++l) acc += GYk[i * mw + l] * ut[l];
                        }
                        pre[i] = acc;
                    }
                    if (j == dkey && dl[k] != 0.0) {
                        /* the delay moves this interval's ends: d x+ / d h = A x+ + [B, W] ut per substep */
                        for (int i = 0; i < n; ++i) {
                            double acc = 0.0;
                            for (int l = 0; l < n; ++l) acc += A[i * n + l] * xn[l];
                            for (int l = 0; l < mw; ++l) acc += BW[i * mw + l] * ut[l];
                            pre[i] += dl[k] * acc;
                        }
                    }
                    for (int b = 0; b < nf; ++b) {
                        double rc = pre[csel[b]];
                        for (int l = 0; l < n; ++l) rc -= Xj[csel[b] * n + l] * xn[l];
                        for (int c = 0; c < nf; ++c) Jm[b * nf + c] = (b == c) - Dg[b] * Gk[csel[b] * mw + m + c];
                        dT[b] = Dg[b] * rc + (fck[b] == j ? -th[b] : 0.0);
                    }
                    if (nf && solve_small(nf, Jm, dT)) fail = 1;
                    for (int i = 0; i < n; ++i) {
                        double acc = pre[i];
                        for (int c = 0; c < nf; ++c) acc += Gk[i * mw + m + c] * dT[c];
                        sj[i] = acc;
                    }
                }
            }
            memcpy(xk, xn, sizeof(double) * n);
        }
    }
    return fail;
}
