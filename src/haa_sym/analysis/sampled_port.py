"""Exact passivity of the continuous port under the sampled controller (issue 24, docs/passivity.md).

The port torque f(t) and the port velocity v(t) are continuous signals; the controller samples
its measurements y (the torque signal and the encoder angle) at Ts and drives the plant through a
zero-order hold. The map f -> v is linear and Ts-periodic. In the frequency-domain lifting
(Araki and Ito; Yamamoto and Khargonekar 1996) the input of frequency w is the sequence of its
harmonics f_k = f(j w_k), w_k = w + k ws (ws = 2 pi / Ts), and the operator acts on it as

    v_k = G_vf(j w_k) f_k + a_k U,    U = c(z) (1/Ts) sum_m G_yf(j w_m) f_m,
    a_k = G_vV(j w_k) (1 - z^-1) / (j w_k),   c = K / (1 - K P_d),   z = exp(j w Ts),

with K(z) the controller's row from y to the voltage (``haa_sym.loop.statespace.controller_batch``)
and P_d(z) the zero-order-hold sampled plant from the voltage to y. That is a diagonal operator
(the plant alone, the voltage held at zero) plus a rank-one one (the sampled feedback):
T = D + a b^T with b_m = c G_yf(j w_m) / Ts. The port is passive iff Re <f, T f> >= 0 for every
f and every w in [0, pi/Ts], i.e. iff the Hermitian part Delta + a b^T + conj(b) a^* is positive
semidefinite, Delta = diag(d_k), d_k = 2 Re G_vf(j w_k) > 0 (the plant's own dissipation, which
the method requires). With p = Delta^-1/2 a, q = Delta^-1/2 conj(b) the rank-two part has the
eigenvalues Re(q^* p) +- sqrt(|p|^2 |q|^2 - Im(q^* p)^2), so

    mu(w) = 1 + Re(q^* p) - sqrt(|p|^2 |q|^2 - Im(q^* p)^2)

is the smallest eigenvalue of I + Delta^-1/2 (a b^T + conj(b) a^*) Delta^-1/2 (the fraction of
the plant's own dissipation the closed loop leaves; 1 with the controller off) and the port is
passive iff mu(w) >= 0 for all w. mu >= 0 is equivalent to |1 + q^* p|^2 >= |p|^2 |q|^2, and
multiplied by |1 - K P_d|^2 to

    f(w; x) = |1 - K (P_d - (1 - z^-1) gamma / Ts)|^2 - |1 - z^-1|^2 A (K B K^*) / Ts^2 >= 0,

a quadratic form in the gains x = (1, P_gain, D_gain) at every frequency (K is affine in them),
as the corrected phase's Re W is: the boundary code's conics take it unchanged. The three
gain-independent aliasing sums are

    A(w) = sum_k |alpha_k|^2 / d_k,  gamma(w) = sum_k beta_k alpha_k / d_k,
    B(w) = sum_k beta_k beta_k^* / d_k,
    alpha_k = G_vV(j w_k) / (j w_k),  beta_k = G_yf(j w_k),

sums of rational functions of s = j w_k; :func:`harmonic_sums` evaluates them exactly to
rounding: the terms |k| <= K directly from the continuous plant, the tail from the Laurent
series at infinity of each summand (Markov parameters, series arithmetic) summed term by term
in closed form (Euler-Maclaurin on (k +- x)^-m, exact to 1e-20 relative for k > K >= 8),
with K chosen so that every |w_k| beyond it is at least twice the series' radius of
convergence (the largest plant pole and zero of d(s)): the truncation of the series after
``N_SERIES`` terms is then below 2^-N_SERIES = 9e-19 (with 4 x the radius, the choice until
issue 24's speed work, the sums agree to 1e-13 relative on HyQ at Ts 0.5-8 ms, SEA and QDD, with
half the explicit harmonics: K = 78 instead of 155 on HyQ at 1 ms).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from haa_sym.analysis.sweep import colgate_factor, gain_rows, phase_excess, product_form
from haa_sym.compiled.cache import BoundedCache, array_key
from haa_sym.errors import ParameterError
from haa_sym.loop.plant import continuous_plant, current_commanded, with_lag
from haa_sym.loop.statespace import controller_batch

__all__ = ["harmonic_sums", "ExactForms", "exact_forms", "HarmonicSums", "N_SERIES", "RADIUS_FACTOR",
           "loop_exact_forms", "passivity_excess", "passivity_tolerance", "passivity_conics", "MEASURES",
           "measure_fields", "deficit_lower_bound"]

# Laurent terms of each summand at infinity; with |w_k| >= RADIUS_FACTOR x the radius of
# convergence beyond the explicit terms, the series' remainder is below RADIUS_FACTOR^-N_SERIES (checked: the last terms below 1e-13 of the largest)
N_SERIES = 60
RADIUS_FACTOR = 2.0
# at least this many explicit harmonics on each side (the Euler-Maclaurin tail starts beyond)
MIN_EXPLICIT = 8
# Bernoulli numbers B_2, B_4, ..., B_16 over (2j)!: Euler-Maclaurin's correction terms
_BERN = np.array([1 / 6, -1 / 30, 1 / 42, -1 / 30, 5 / 66, -691 / 2730, 7 / 6, -3617 / 510])
_FACT = np.array([float(np.prod(np.arange(1, 2 * j + 1))) for j in range(1, 9)])


@dataclass(frozen=True)
class HarmonicSums:
    """The gain-independent aliasing sums at ``omega`` (rad/s): ``A`` (n_omega,), ``gamma``
    (n_omega, n_y) and ``B`` (n_omega, n_y, n_y, Hermitian), and ``K`` the explicit harmonics
    on each side."""

    omega: np.ndarray
    A: np.ndarray
    gamma: np.ndarray
    B: np.ndarray
    K: int


def _markov(A, B, C, n: int, scale: float) -> np.ndarray:
    """Laurent coefficients of C (sI - A)^-1 B in (scale/s): entry m is C (A/scale)^(m-1) B / scale
    (m >= 1; entry 0 is 0), shape (n, rows, cols)."""
    out = np.zeros((n, C.shape[0], B.shape[1]))
    X = B / scale
    As = A / scale
    for m in range(1, n):
        out[m] = C @ X
        X = As @ X
    return out


def _mirror(c: np.ndarray) -> np.ndarray:
    """Series of F(-s) from that of F(s) (in 1/s): the coefficient of w^m times (-1)^m."""
    return c * ((-1.0) ** np.arange(c.shape[0]))[:, None, None]


def _mul(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Product of two matrix series (n terms), entry m = sum_i a_i @ b_(m-i) (a 1 x 1 factor
    scales): one contraction against b's lower-triangular Toeplitz arrangement (the double loop
    over m and i cost 7 ms a product, 0.35 s in a contact scan's sums)."""
    scalar = b.shape[1:] == (1, 1) and a.shape[2] != 1
    a, b = a[:n], b[:n]
    k = np.arange(n)
    lag = k[:, None] - k[None, :]                                   # m - i
    Bt = np.where((lag >= 0)[:, :, None, None], b[np.maximum(lag, 0)], 0)   # (m, i, rows, cols)
    if scalar:
        return np.einsum("ijk,mi->mjk", a, Bt[:, :, 0, 0])
    return np.einsum("ijk,mikl->mjl", a, Bt)


def _reciprocal_d(d: np.ndarray, n: int) -> np.ndarray:
    """Series of 1/d(s) for a scalar d = d_2 w^2 + d_3 w^3 + ... (w = scale/s): returned as the
    series of w^2 / d (the caller multiplies by w^-2, a shift), n terms."""
    e = d[2:, 0, 0]
    r = np.zeros(n)
    r[0] = 1.0 / e[0]
    for m in range(1, n):
        s = sum(e[i] * r[m - i] for i in range(1, min(m, e.size - 1) + 1))
        r[m] = -s / e[0]
    return r[:, None, None]


def _tail_powers(x: np.ndarray, K: int, n: int) -> np.ndarray:
    """T_m(x) = sum_{k > K} [(k + x)^-m + (-1)^m (k - x)^-m] for m = 1..n-1 (row m; row 0 zero),
    0 <= x <= 1/2, by Euler-Maclaurin from a = K + 1 (error below 1e-20 relative for a >= 9)."""
    a = K + 1.0
    out = np.zeros((n, x.size))
    p, q = a + x, a - x
    for m in range(1, n):
        sgn = (-1.0) ** m
        if m == 1:
            integral = np.log(q / p)
        else:
            integral = (p ** (1 - m) + sgn * q ** (1 - m)) / (m - 1)
        total = integral + 0.5 * (p ** -m + sgn * q ** -m)
        rising = float(m)                           # m (m+1) ... (m + 2j - 2)
        for j in range(1, _BERN.size + 1):
            # g^(2j-1)(a) of (k + c)^-m is -(m)_(2j-1) (a + c)^(-m-2j+1)
            deriv = -rising * (p ** (-m - 2 * j + 1) + sgn * q ** (-m - 2 * j + 1))
            total = total - _BERN[j - 1] / _FACT[j - 1] * deriv
            rising *= (m + 2 * j - 1) * (m + 2 * j)
        out[m] = total
    return out


# terms of the oscillating tails' expansion (:func:`_tail_powers_delayed`), and how far beyond
# the radius of that expansion's terms' growth the first tail harmonic must sit
N_OSC = 40
OSC_MARGIN = 4.0


def _tail_powers_delayed(x: np.ndarray, K: int, n: int, theta: float) -> np.ndarray:
    """T_m(x) = sum_{k > K} [q^k (k + x)^-m + (-1)^m conj(q)^k (k - x)^-m], q = exp(-j theta), for
    m = 2..n-1 (rows 0, 1 zero), theta not a multiple of 2 pi: the tails of the delayed hold's
    sums, whose harmonics carry exp(-j k theta).

    Sum_{k >= a} q^k g(k) = q^a [(1 - q E)^-1 g](a) with E = e^D the shift, so it is
    q^a sum_j b_j g^(j)(a), b_j the Taylor coefficients of 1 / (1 - q e^t) at 0 (their radius is
    rho = the distance of theta to the nearest multiple of 2 pi) and g^(j)(a) of (k + c)^-m equal
    to (-1)^j (m)_j (a + c)^(-m-j): the terms shrink by (m + j) / (rho (a + c)) each, at most
    1 / OSC_MARGIN for the K that :func:`harmonic_sums` chooses, so N_OSC terms leave
    OSC_MARGIN^-N_OSC = 8e-25 of the first."""
    q = np.exp(-1j * theta)
    b = np.zeros(N_OSC, complex)
    b[0] = 1.0 / (1.0 - q)
    fact = np.cumprod(np.concatenate([[1.0], np.arange(1.0, N_OSC)]))          # j!
    for j in range(1, N_OSC):                  # (1 - q e^t) sum b_j t^j = 1
        b[j] = q / (1.0 - q) * np.sum(b[j - 1::-1][:j] / fact[1:j + 1])
    a = K + 1.0
    out = np.zeros((n, x.size), complex)
    for m in range(2, n):
        rising = np.ones(N_OSC)
        rising[1:] = np.cumprod(m + np.arange(N_OSC - 1.0))                    # (m)_j
        alt = rising * (-1.0) ** np.arange(N_OSC)
        # k > K with (k + x)^-m and q; k < -K as k' > K with (-1)^m (k' - x)^-m and conj(q), whose
        # coefficients are conj(b) (1 / (1 - conj(q) e^t) is the conjugate for real t)
        for c, qq, bb, sgn in ((x, q, b, 1.0), (-x, np.conj(q), np.conj(b), (-1.0) ** m)):
            powers = (a + c)[None, :] ** (-m - np.arange(N_OSC)[:, None])      # (N_OSC, n_omega)
            out[m] += sgn * qq ** a * ((bb * alt) @ powers)
    return out


def _d_zeros(A, b_f, c_v) -> np.ndarray:
    """Finite zeros of d(s) = G_vf(s) + G_vf(-s) (the invariant zeros of its realisation)."""
    n = A.shape[0]
    Ad = scipy.linalg.block_diag(A, -A.T)
    Bd = np.concatenate([b_f, c_v.T])
    Cd = np.concatenate([c_v, -b_f.T], axis=1)
    M = np.block([[Ad, Bd], [Cd, np.zeros((1, 1))]])
    N = scipy.linalg.block_diag(np.eye(2 * n), np.zeros((1, 1)))
    w = scipy.linalg.eigvals(M, N)
    return w[np.isfinite(w)]


def _relative_degree(c, b, A) -> int:
    """The first m with c A^m b not zero (against rounding: 1e-13 of |c| |A^m b|), at most n."""
    x = b[:, 0]
    for m in range(A.shape[0]):
        if abs(c @ x) > 1e-13 * np.linalg.norm(c) * np.linalg.norm(x):
            return m
        x = A @ x
    return A.shape[0]


def _responses(A, b_u, b_f, c_v, C_y, s, shift=None):
    """G_vV(s), G_vf(s) (shape of ``s``) and G_yf(s) (shape of ``s`` + (n_y,)) of the continuous
    plant at the complex frequencies ``s``.

    Through the complex Schur form T = Q^* Ab Q of the balanced A (computed once): (sI - A)^-1 b
    by back substitution vectorised over all s, n^2/2 array operations instead of one n x n
    solve per harmonic (HyQ's 1000 frequencies x 311 harmonics: 2.3 s -> 0.5 s). The change of
    basis mixes b's exact zeros, so at high |s| the terms c A^m b / s^(m+1), m < r (zero for a
    response of relative degree r) would come out as rounding of size eps |c| |b| / |s| against
    a value ~|c A^r b| / |s|^(r+1); there the identity c (sI - A)^-1 b = c (sI - A)^-1 A^r b / s^r
    (exact when c A^m b = 0 for m < r) is used (above ``shift`` rad/s, default a quarter of A's
    largest eigenvalue modulus: below it the shifted form's rounding grows like (|A| / |s|)^r,
    above it the plain form's like |s| / |A|). Against 40-digit solves on the bundled actuators
    from 3 to 6e5 rad/s: below 1.3e-11 relative to |G| (one pivoted n x n solve per s: up to
    5e-11); the sums move by at most 4e-10 relative against the per-s solves, far below the
    test's tolerance (``test_schur_responses_equal_direct_solves``)."""
    n = A.shape[0]
    if shift is None:
        ev = np.abs(np.linalg.eigvals(A))
        shift = max(float(ev.max(initial=0.0)), 1.0) / 4
    # the pairs (row, column) the sums need: G_vV, G_vf, G_yf (one per measurement)
    pairs = [(c_v, b_u), (c_v, b_f)] + [(C_y[i:i + 1], b_f) for i in range(C_y.shape[0])]
    rdeg = [_relative_degree(c[0], b, A) for c, b in pairs]
    rows = np.concatenate([c for c, _ in pairs])                         # (n_pairs, n)
    # right-hand sides, each once: b (plain form) and A^r b (shifted form) per distinct (b, r)
    plain_key = [0 if b is b_u else 1 for _, b in pairs]
    shift_keys = sorted(set(zip(plain_key, rdeg)))
    shift_key = [shift_keys.index(k) for k in zip(plain_key, rdeg)]
    base = (b_u, b_f)
    B_plain = np.concatenate(base, axis=1)
    B_shift = np.concatenate([np.linalg.matrix_power(A, r) @ base[j] for j, r in shift_keys], axis=1)
    # balanced first (A's entries span many decades: rad, rad/s, A, Nm): A = S Ab S^-1
    Ab, Sm = scipy.linalg.matrix_balance(A)
    T, Q = scipy.linalg.schur(Ab.astype(complex), output="complex")
    rows_q = rows @ Sm @ Q
    flat = s.ravel()
    out = np.empty((flat.size, len(pairs)), complex)
    far = np.abs(flat) > shift
    r_arr = np.array(rdeg, float)
    # each frequency solves only the right-hand sides of its form (plain near, shifted far)
    for sel, B, col, shifted in ((np.flatnonzero(~far), B_plain, plain_key, False),
                                 (np.flatnonzero(far), B_shift, shift_key, True)):
        Y = Q.conj().T @ np.linalg.solve(Sm, B)                          # in Schur coordinates
        step = max(1, 2 ** 18 // (Y.shape[1] * n))
        for a in range(0, sel.size, step):
            idx = sel[a:a + step]
            sb = flat[idx, None]                                         # (m, 1)
            x = [None] * n
            for i in range(n - 1, -1, -1):
                acc = np.broadcast_to(Y[i], (idx.size, Y.shape[1])).astype(complex)
                for j in range(i + 1, n):
                    if T[i, j] != 0:
                        acc = acc + T[i, j] * x[j]
                x[i] = acc / (sb - T[i, i])
            g = sum(rows_q[:, i] * x[i][:, col] for i in range(n))       # (m, n_pairs)
            out[idx] = g / sb ** r_arr if shifted else g
    out = out.reshape(s.shape + (len(pairs),))
    return out[..., 0], out[..., 1], out[..., 2:]


def harmonic_sums(A, b_u, b_f, c_v, C_y, Ts: float, omega, *, source: str = "the plant",
                  delay: float = 0.0) -> HarmonicSums:
    """The aliasing sums A, gamma, B of the module docstring at ``omega`` (rad/s, in (0, pi/Ts]).

    Parameters
    ----------
    A : (n, n) array
        Continuous plant matrix (the drive's lag included).
    b_u, b_f : (n, 1) arrays
        Columns of the held command (V_m) and of the port torque (T_dist).
    c_v : (1, n) array
        Row of the port velocity (rad/s).
    C_y : (n_y, n) array
        Rows of the sampled measurements (the order of the controller's inputs).
    Ts : float
        Sampling time, s.
    omega : array_like
        Frequencies, rad/s.
    source : str
        What to name in a refusal.
    delay : float
        The drive's dead time d (s, >= 0): the command is held from kTs + d, so the hold's
        harmonics carry exp(-j w_k d) (gamma's only: A and B hold |.|^2 and no command).

    Raises
    ------
    ParameterError
        The plant's own port is not strictly passive (d(jw) has a zero on the imaginary axis
        away from 0: no dissipation at some frequency), or a summand decays too slowly (a
        measurement with a direct response to the port torque).
    """
    A, b_u, b_f, c_v, C_y = (np.asarray(m, float) for m in (A, b_u, b_f, c_v, C_y))
    omega = np.asarray(omega, float).ravel()
    ws = 2 * np.pi / Ts
    n = A.shape[0]
    zeros = _d_zeros(A, b_f, c_v)
    poles = np.linalg.eigvals(A)
    # the pencil's infinite eigenvalues (d has relative degree 2) may come out as huge finite
    # ones: zeros beyond 1e4 x the largest plant pole are taken as infinite (the series check
    # below catches a real zero that far out)
    p_max = float(np.max(np.abs(poles), initial=0.0))
    zeros = zeros[np.abs(zeros) <= 1e4 * max(p_max, 1.0)]
    scale = max(float(np.max(np.abs(np.concatenate([zeros, poles])), initial=0.0)), 1.0)
    # the plant's own port must dissipate at every frequency (d_k > 0): a zero of d on the
    # imaginary axis away from the origin is a lossless frequency, where the test is singular
    on_axis = np.abs(zeros.real) <= 1e-9 * np.maximum(np.abs(zeros), 1.0)
    away = np.abs(zeros) > 1e-6 * scale
    d_probe = 2 * np.real(c_v @ np.linalg.solve(1j * scale * np.eye(n) - A, b_f))[0, 0]
    if (on_axis & away).any() or not d_probe > 0:
        raise ParameterError(
            f"passivity = 'exact': the port of {source} is not strictly passive on its own (its "
            "velocity's response to the port torque, the voltage held at zero, has no dissipation at "
            f"{'some frequency' if d_probe > 0 else 'high frequency'}); allowed: a port body with "
            "physical damping (the exact test divides by it), or passivity = 'corrected_phase'")
    # Laurent series at infinity in w = scale/s
    g_vV = _markov(A, b_u, c_v, N_SERIES + 4, scale)
    g_vf = _markov(A, b_f, c_v, N_SERIES + 4, scale)
    g_yf = _markov(A, b_f, C_y, N_SERIES + 4, scale)
    if np.any(np.abs(g_yf[1]) > 1e-12 * np.abs(g_yf).max(initial=1.0)):
        raise ParameterError(
            f"passivity = 'exact': a measurement of {source} responds directly to the port torque "
            "(relative degree 1), so its samples are not defined at the jumps; allowed: "
            "measurements of relative degree >= 2 from the port torque (angles, spring torques), "
            "or passivity = 'corrected_phase'")
    d = g_vf + _mirror(g_vf)
    if not abs(d[2, 0, 0]) > 0:
        raise ParameterError(f"passivity = 'exact': the port of {source} has no damping at high "
                             "frequency; allowed: a port body with viscous damping, or "
                             "passivity = 'corrected_phase'")
    N = N_SERIES + 2
    inv_d = _reciprocal_d(d, N)                          # w^2 / d
    alpha = np.concatenate([np.zeros((1, 1, 1)), g_vV[:-1]]) / scale   # G_vV / s = G_vV w / scale
    # summands times w^-2 (the 1/d shift): start from power 2 of the products below
    R_A = _mul(_mul(alpha, _mirror(alpha), N), inv_d, N)
    R_g = _mul(_mul(g_yf, alpha, N), inv_d, N)
    R_B = _mul(_mul(g_yf, np.transpose(_mirror(g_yf), (0, 2, 1)), N), inv_d, N)
    # the series must converge at RADIUS_FACTOR x scale: its last terms negligible there
    for R in (R_A, R_g, R_B):
        top = np.abs(R[2:]).max(axis=(1, 2)) / RADIUS_FACTOR ** np.arange(N - 2)
        if not top[-4:].max() <= 1e-13 * top.max():
            raise ParameterError(f"passivity = 'exact': the aliasing series of {source} do not converge "
                                 "(a zero of the port's dissipation far beyond the plant's poles); allowed: "
                                 "passivity = 'corrected_phase' for this actuator")
    # the explicit harmonics: |w_k| > RADIUS_FACTOR scale beyond K
    K = max(MIN_EXPLICIT, int(np.ceil(RADIUS_FACTOR * scale / ws)) + 1)
    theta = (ws * delay) % (2 * np.pi)                  # exp(-j k ws d) = exp(-j k theta)
    rho = min(theta, 2 * np.pi - theta)
    oscillating = rho > 1e-9
    if oscillating:
        # the oscillating tails' expansion needs rho (K + 1/2) >= OSC_MARGIN (N + N_OSC)
        K = max(K, int(np.ceil(OSC_MARGIN * (N + N_OSC) / rho)))
        if K > 50000:
            raise ParameterError(f"passivity = 'exact' with delay_drive = {delay!r} s at Ts = {Ts!r} s: the dead "
                                 "time is within 1e-3 Ts of a whole number of samples but not on it, and its "
                                 f"aliasing sums would need {K} harmonics a side; allowed: a dead time a whole "
                                 "number of samples, or at least 1e-3 Ts away from one")
    x = omega / ws
    ks = np.arange(-K, K + 1)
    s = 1j * (omega[:, None] + ks[None, :] * ws)                        # (n_omega, 2K+1)
    G_vV, G_vf, G_yf = _responses(A, b_u, b_f, c_v, C_y, s)
    dk = 2 * G_vf.real
    al = G_vV / s
    A_sum = np.sum(np.abs(al) ** 2 / dk, axis=1)
    # the delayed hold: exp(-j w_k d) = exp(-j w d) exp(-j k theta); whole samples: exp(-j w d) only
    g_sum = np.einsum("wk,wky->wy", al * np.exp(-1j * ks * theta) / dk, G_yf)
    B_sum = np.einsum("wk,wky,wkz->wyz", 1 / dk, G_yf, np.conj(G_yf))
    # the tail: sum over |k| > K of sum_m R_m (scale/s_k)^m, R's powers shifted by -2 (1/d)
    T = _tail_powers(x, K, N)                                            # (N, n_omega)
    pw = (scale / (1j * ws)) ** np.arange(N)                             # (scale/(j ws))^m
    tail = {}
    for name, R in (("A", R_A), ("g", R_g), ("B", R_B)):
        # coefficient of w^m in R (with w^-2) is R[m + 2]
        c = np.zeros_like(R)
        c[:N - 2] = R[2:]
        if np.any(np.abs(c[:2]) > 1e-9 * np.abs(c).max(initial=1.0)):
            raise ParameterError(f"passivity = 'exact': an aliasing sum of {source} does not converge "
                                 "absolutely (a summand of relative degree < 2); allowed: the port and "
                                 "measurements of the bundled structures, or passivity = 'corrected_phase'")
        Tm = _tail_powers_delayed(x, K, N, theta) if name == "g" and oscillating else T
        tail[name] = np.einsum("m,mw,mij->wij", pw, Tm, c)
    A_sum = A_sum + tail["A"][:, 0, 0].real
    g_sum = (g_sum + tail["g"][:, :, 0]) * np.exp(-1j * omega * delay)[:, None]
    B_sum = B_sum + tail["B"]
    B_sum = 0.5 * (B_sum + np.conj(np.transpose(B_sum, (0, 2, 1))))
    return HarmonicSums(omega, A_sum, g_sum, B_sum, K)


@dataclass(frozen=True)
class ExactForms:
    """Gain-affine pieces of the exact test on a frequency grid, x = (1, P_gain, D_gain):
    ``delta`` (n_omega, 3) the return difference 1 - K P_d, ``u`` (n_omega, 3) the aliased part
    (1 - z^-1) K gamma / Ts (so q^* p = u.x / delta.x), ``S`` (n_omega, 3, 3) Hermitian with
    x^T S x = |1 - z^-1|^2 A K B K^* / Ts^2 (= |p|^2 |q|^2 |delta.x|^2)."""

    omega: np.ndarray
    delta: np.ndarray
    u: np.ndarray
    S: np.ndarray

    def conics(self) -> np.ndarray:
        """f(w; x) = |(delta + u).x|^2 - x^T S x on the monomials (1, P, D, P^2, P D, D^2):
        real, shape (6, n_omega). f >= 0 at a frequency iff mu(w) >= 0 there."""
        e = self.delta + self.u
        ee = e[:, :, None] * np.conj(e[:, None, :]) - self.S
        return np.stack([ee[:, 0, 0].real, 2 * ee[:, 0, 1].real, 2 * ee[:, 0, 2].real, ee[:, 1, 1].real,
                         2 * ee[:, 1, 2].real, ee[:, 2, 2].real])

    def monomial_forms(self):
        """rho = |delta.x|^2, w = (u.x) conj(delta.x) and s = x^T S x as coefficients on the
        monomials (1, P, D, P^2, P D, D^2): (6, n_omega) real, complex, real (cached)."""
        cached = self.__dict__.get("_mono")
        if cached is None:
            def sym(M):                     # M_ij x_i x_j with x real: the symmetric part's monomials
                return np.stack([M[:, 0, 0], M[:, 0, 1] + M[:, 1, 0], M[:, 0, 2] + M[:, 2, 0], M[:, 1, 1],
                                 M[:, 1, 2] + M[:, 2, 1], M[:, 2, 2]])
            dd = self.delta[:, :, None] * np.conj(self.delta[:, None, :])
            ud = self.u[:, :, None] * np.conj(self.delta[:, None, :])
            cached = (sym(dd).real.copy(), sym(ud), sym(self.S).real.copy())
            object.__setattr__(self, "_mono", cached)
        return cached

    def worst(self, X: np.ndarray):
        """(-min_w mu(w), argmin w) at the gain rows ``X`` (n, 3): the dissipation deficit
        (<= 0: passive; -1 with the controller off). rho, w and s are quadratic in the gains:
        one product of the points' monomials with the (6, n_omega) coefficients each, instead of
        forming delta.x and u.x per point and frequency."""
        R, W, S = self.monomial_forms()
        X = np.asarray(X, float)
        mono = np.stack([X[:, 0] * X[:, 0], X[:, 0] * X[:, 1], X[:, 0] * X[:, 2], X[:, 1] * X[:, 1],
                         X[:, 1] * X[:, 2], X[:, 2] * X[:, 2]], axis=1)
        rho = mono @ R
        w = mono @ W
        s = mono @ S
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = (rho + w.real - np.sqrt(np.maximum(s * rho - w.imag ** 2, 0.0))) / rho
        j = np.argmin(mu, axis=1)
        return -mu[np.arange(X.shape[0]), j], self.omega[j]


def exact_forms(sums: HarmonicSums, P_d, K_aff, Ts: float) -> ExactForms:
    """The pieces of :class:`ExactForms` from the aliasing sums, the sampled plant ``P_d``
    (n_omega, n_y: the voltage to the measurements) and the controller's affine coefficients
    ``K_aff`` (n_omega, 3, n_y: rows for 1, P_gain, D_gain; u = K y, the controller's own signs)."""
    z = np.exp(1j * sums.omega * Ts)
    h = 1 - 1 / z
    unit = np.zeros(3)
    unit[0] = 1.0
    delta = unit[None, :] - np.einsum("wiy,wy->wi", K_aff, P_d)
    u = (h / Ts)[:, None] * np.einsum("wiy,wy->wi", K_aff, sums.gamma)
    a0 = (np.abs(h) ** 2 * sums.A / Ts ** 2)
    S = a0[:, None, None] * np.einsum("wiy,wyz,wjz->wij", K_aff, sums.B, np.conj(K_aff))
    S = 0.5 * (S + np.conj(np.transpose(S, (0, 2, 1))))
    return ExactForms(sums.omega, delta, u, S)


def _loop_pieces(loop):
    """The continuous plant's matrices the exact test needs (A, b_u, b_f, c_v, C_y), checking that
    the loop is one it handles."""
    opt, params = loop.options, loop.params
    port = opt.structure.port
    if port == "encoder_average":
        raise ParameterError("passivity = 'exact' with port = 'encoder_average': that port reads the "
                             "controller's sampled estimate, not a continuous velocity; allowed: port = "
                             "'dtheta_<body>' with passivity = 'exact', or passivity = 'corrected_phase'")
    # the plant the loop's P_d is sampled from (ClosedLoop.plant): a current-commanded structure
    # imposes the current, so its command column and its mechanics are those of current_commanded
    cont = with_lag(current_commanded(continuous_plant(params.plant, loop.backend), loop.structure.command == "current"),
                    params.drive.tau_drive)
    names = cont.output_names
    # the controller's inputs, in its order (haa_sym.loop.statespace.CONTROLLER_INPUTS)
    C_y = cont.C[[names.index("theta_encoder"), names.index(loop.torque_output)]]
    c_v = cont.C[[names.index(port)]]
    return cont.A, cont.B[:, :1], cont.B[:, 2:3], c_v, C_y


def loop_exact_forms(loop, omega, beta: float, alpha: float) -> ExactForms:
    """:class:`ExactForms` of ``loop`` at ``omega`` (rad/s) for the torque gains beta, alpha;
    memoised per loop structure, grid and gains (a map reuses one)."""
    Ts = loop.params.controller.Ts
    omega = np.asarray(omega, float).ravel()

    def sums():
        A, b_u, b_f, c_v, C_y = _loop_pieces(loop)
        return harmonic_sums(A, b_u, b_f, c_v, C_y, Ts, omega, source=str(loop.params.source),
                             delay=float(loop.params.drive.delay_drive))

    def build():
        S = _SUMS.get((array_key(loop.plant.Phi, loop.plant.Gamma, loop.plant.C, omega), loop.options.structure.port,
                       loop.torque_output, loop.backend, float(loop.params.drive.delay_drive)), sums)
        P_d = loop.plant.frequency_response(omega, outputs=("theta_encoder", loop.torque_output),
                                            inputs=("V_m",))[:, 0, :].T          # (n_omega, 2)
        Ac, Bc, Cc, Dc = controller_batch(loop, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], beta, alpha)
        z = np.exp(1j * omega * Ts)
        m = Ac.shape[1]
        # K(z) = C (zI - A)^-1 B + D from (theta_encoder, T_meas) to V, at the three points
        Mz = z[None, :, None, None] * np.eye(m) - Ac[:, None]
        Xz = np.linalg.solve(Mz, np.broadcast_to(Bc[:, None, :, :2], (3, omega.size, m, 2)))
        Kz = np.einsum("pj,pwjy->pwy", Cc[:, 0, :], Xz) + Dc[:, None, 0, :2]   # (3, n_omega, 2)
        K_aff = np.stack([Kz[0], Kz[1] - Kz[0], Kz[2] - Kz[0]], axis=1)      # (n_omega, 3, 2)
        return exact_forms(S, P_d, K_aff, Ts)
    key = (array_key(loop.plant.Phi, loop.plant.Gamma, loop.plant.C, omega), loop.options.structure.port,
           loop.torque_output, loop.backend, tuple((e.numerator, e.denominator) for e in loop.elements.values()),
           tuple(loop.const), float(beta), float(alpha))
    return _FORMS.get(key, build)


_SUMS = BoundedCache(16)
_FORMS = BoundedCache(32)


def passivity_excess(loop, P, D, beta: float, alpha: float, omega=None):
    """The one passivity measure of the maps, the curves' probes, the contact scan and Table 2:
    ``(excess, omega_worst)`` at the gain points (flat P, D) on ``omega`` (default the options'
    grid), by the options' ``passivity`` test:

    * ``"corrected_phase"`` (the paper's): the worst corrected phase of Z beyond +-90 deg, deg;
    * ``"exact"``: the dissipation deficit -min_w mu(w), dimensionless (module docstring).

    A point is passive when its loop is stable and excess <= :func:`passivity_tolerance`."""
    conv = loop.options.conventions
    X = gain_rows(P, D)
    if X.shape[0] == 0:
        return np.full(0, np.nan), np.full(0, np.nan)
    if conv.passivity == "exact":
        w = loop.options.numerics.omega(loop.params.controller.Ts) if omega is None else omega
        return loop_exact_forms(loop, w, beta, alpha).worst(X)
    coef = loop.loop_coefficients(omega, beta, alpha)
    return phase_excess(X, coef.Z_num, coef.Z_den, coef.omega, loop.params.controller.Ts, conv.colgate)


# the result field of each test's measure: the paper's is an angle, the exact test's a fraction
# of the port's own dissipation; a result holds both fields, the one of the test that did not
# run NaN (docs/passivity.md, "Results")
MEASURES = {"corrected_phase": "phase_excess_deg", "exact": "dissipation_deficit"}


def measure_fields(loop, excess) -> dict:
    """``{"phase_excess_deg": ..., "dissipation_deficit": ...}``: :func:`passivity_excess`'s
    values under the name of the options' test, NaN (same shape) under the other's."""
    excess = np.asarray(excess, float)
    ran = MEASURES[loop.options.conventions.passivity]
    return {name: excess if name == ran else np.full(excess.shape, np.nan) for name in MEASURES.values()}


def deficit_lower_bound(loop, P, D, beta: float, alpha: float, stride: int = 16):
    """``(bound, omega)``: the exact test's deficit on every ``stride``-th frequency of the options'
    grid, a lower bound of :func:`passivity_excess`'s (the same mu values at those frequencies,
    the maximum over fewer of them): a point whose bound exceeds the tolerance is not passive,
    at 1/stride of the cost. For screening many points (the reproduction's comparison of the
    tests); the deficit itself is :func:`passivity_excess`."""
    if loop.options.conventions.passivity != "exact":
        raise ParameterError("deficit_lower_bound is the exact test's; allowed: a loop with passivity = 'exact'")
    X = gain_rows(P, D)
    if X.shape[0] == 0:
        return np.full(0, np.nan), np.full(0, np.nan)
    w = loop.options.numerics.omega(loop.params.controller.Ts)
    F = loop_exact_forms(loop, w, beta, alpha)
    k = np.arange(0, w.size, max(int(stride), 1))
    return ExactForms(F.omega[k], F.delta[k], F.u[k], F.S[k]).worst(X)


def passivity_tolerance(loop) -> float:
    """The options' tolerance of :func:`passivity_excess`'s measure (deg or dimensionless)."""
    conv = loop.options.conventions
    return conv.passivity_tol_exact if conv.passivity == "exact" else conv.passivity_tol_deg


def passivity_conics(loop, omega, beta: float, alpha: float, cached: bool = False) -> np.ndarray:
    """Per frequency, the quadratic form in (1, P, D, P^2, P D, D^2) whose sign is the test's
    (shape (6, n_omega), complex for the corrected phase, whose real part is Re W; real for
    the exact test): the conics of :mod:`haa_sym.analysis.boundaries.passivity`."""
    conv = loop.options.conventions
    if conv.passivity == "exact":
        return loop_exact_forms(loop, omega, beta, alpha).conics().astype(complex)
    coef = loop.loop_coefficients(omega, beta, alpha, cached=cached)
    return product_form(coef.Z_num, coef.Z_den) * colgate_factor(coef.omega, loop.params.controller.Ts, conv.colgate)
