/* C reference of the identification integrators (pmalab/identify/hysteresis.py).
 *
 * Same algorithms, same double-precision arithmetic, compiled by bench/bench_identify.py
 * with `gcc -O2` (no -ffast-math, matching numba's fastmath=False) to measure how close
 * the numba kernels get to plain C.  Position x in mm, h in N.
 */
#include <math.h>
#include <stddef.h>

/* Bouc-Wen, n = 1: exact integration on each linear segment of x, zero crossing solved. */
void bw_h1(const double *x, long N, double A, double beta, double gamma, double h0,
           double psi_v, double psi_h, double psi_x, double x_c, double *h)
{
    double hk = h0;
    h[0] = h0;
    for (long k = 0; k < N - 1; k++) {
        double dx = x[k + 1] - x[k];
        if (dx == 0.0) { h[k + 1] = hk; continue; }
        double sigma = dx > 0.0 ? 1.0 : -1.0;
        double s = fabs(dx);
        double xs = (x[k] + 0.5 * dx > x_c) ? 1.0 : -1.0;
        double drive = sigma * A;
        for (int piece = 0; piece < 2; piece++) {
            double sh;
            if (hk > 0.0) sh = 1.0;
            else if (hk < 0.0) sh = -1.0;
            else {
                sh = drive > 0.0 ? 1.0 : (drive < 0.0 ? -1.0 : 0.0);
                if (sh == 0.0) break;
            }
            double lam = beta + sh * (gamma * sigma + psi_v + psi_x * xs * sigma) + psi_h * sigma;
            if (fabs(lam) * s < 1e-12) {
                double hn = hk + drive * s;
                if (hn * sh < 0.0 && hk * sh > 0.0) {
                    double sz = -hk / drive;
                    hk = 0.0; s -= sz; continue;
                }
                hk = hn; break;
            }
            double hinf = drive / lam;
            double hn = hinf + (hk - hinf) * exp(-lam * s);
            if (hk * sh > 0.0 && hn * sh < 0.0) {
                double sz = -log(hinf / (hinf - hk)) / lam;
                hk = 0.0; s -= sz;
                if (s <= 0.0) break;
                continue;
            }
            hk = hn; break;
        }
        h[k + 1] = hk;
    }
}

static double bw_rate(double h, double sigma, double xs, double A, double beta, double gamma,
                      double n, double psi_v, double psi_h, double psi_x)
{
    double ah = fabs(h);
    double hn = ah > 0.0 ? pow(ah, n) : 0.0;
    double sh = h > 0.0 ? 1.0 : (h < 0.0 ? -1.0 : 0.0);
    return A - hn * (beta * sigma * sh + gamma + psi_v * sigma + psi_h * sh + psi_x * xs);
}

/* Bouc-Wen, general n: RK4 with 1 + ceil(4·|dx|·L) sub-steps (≤ 64). */
void bw_rk4(const double *x, long N, double A, double beta, double gamma, double n, double h0,
            double psi_v, double psi_h, double psi_x, double x_c, double *h)
{
    double hk = h0;
    double lip0 = fabs(beta) + fabs(gamma) + fabs(psi_v) + fabs(psi_h) + fabs(psi_x);
    h[0] = h0;
    for (long k = 0; k < N - 1; k++) {
        double dx = x[k + 1] - x[k];
        if (dx == 0.0) { h[k + 1] = hk; continue; }
        double sigma = dx > 0.0 ? 1.0 : -1.0;
        double ah = fabs(hk);
        double lip = n * lip0 * (ah > 0.0 ? pow(ah, n - 1.0) : (n == 1.0 ? 1.0 : 0.0));
        int m = 1 + (int)ceil(4.0 * fabs(dx) * lip);
        if (m > 64) m = 64;
        double dxs = dx / m;
        double xk = x[k];
        for (int j = 0; j < m; j++) {
            double xa = xk + j * dxs;
            double xs = (xa + 0.5 * dxs > x_c) ? 1.0 : -1.0;
            double k1 = bw_rate(hk, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x);
            double k2 = bw_rate(hk + 0.5 * dxs * k1, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x);
            double k3 = bw_rate(hk + 0.5 * dxs * k2, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x);
            double k4 = bw_rate(hk + dxs * k3, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x);
            hk = hk + dxs * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0;
        }
        h[k + 1] = hk;
    }
}

/* Duhem (Coleman-Hodgdon), exact for piecewise-linear x. */
void duhem(const double *x, long N, double alpha, double a, double b, double h0,
           double psi_alpha, double psi_b, double *h)
{
    double hk = h0;
    h[0] = h0;
    for (long k = 0; k < N - 1; k++) {
        double dx = x[k + 1] - x[k];
        if (dx == 0.0) { h[k + 1] = hk; continue; }
        double sigma = dx > 0.0 ? 1.0 : -1.0;
        double s = fabs(dx);
        double al = alpha * (1.0 + psi_alpha * sigma);
        double bb = b * (1.0 + psi_b * sigma);
        double z = al * s;
        double E = exp(-z);
        double G = -expm1(-z);
        double S = fabs(al) > 1e-12 ? G / al : s;
        hk = hk * E + G * a * x[k] + (bb - a) * sigma * S + a * sigma * s;
        h[k + 1] = hk;
    }
}
