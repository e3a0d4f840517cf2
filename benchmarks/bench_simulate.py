"""The nonlinear simulation (issue 19): controller steps per second, side by side with baselines.

HyQ at P_gain = 200 Nm/rad, D_gain = 5 Nms/rad, a 1 Nm disturbance step, Ts = 1 ms:

(1) voltage saturation (24 V) + quantisation (4096-count encoder, 0.01 Nm torque) + torque noise
    (5 mNm rms): the exact ZOH between samples; target >= 1e6 steps/s;
(2) Coulomb friction (rotor 0.02 Nm, leg 0.5 Nm, smooth tanh model, v_s = 0.01 rad/s) with the
    same saturation: integrating substeps chosen per sample by step doubling (rtol 1e-6);
    target >= 1e5 steps/s.

Each case is timed three ways in one run: ``simulate`` (the generated C sample loop; for (2) the
whole call), a plain
numpy loop over the samples with the same exact ZOH matrices (case 1 only: the competent Python
baseline), and a straightforward ``scipy.integrate.solve_ivp`` loop (LSODA, rtol 1e-8, atol 1e-10,
one call per sample with the voltage held; timed on the first ``IVP_SAMPLES`` samples). Also a
batch of 100 x 50 gain points (``simulate_batch``, 0.5 s each, case 1's limits). Steps per
second are per core (one thread). Writes ``results_simulate.json`` into ``$HAA_SYM_BENCH_DIR``.
Usage: python benchmarks/bench_simulate.py
"""
from __future__ import annotations

import math
import time

import numpy as np
import scipy.integrate

from timing import Run, best
from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import _Setup, _run, simulate, simulate_batch
from haa_sym.loop.plant import continuous_plant
from haa_sym.loop.statespace import controller_batch
from haa_sym.model.limits import Limits

P_GAIN, D_GAIN = 200.0, 5.0
SAT_QUANT = Limits(V_max=24.0, encoder_counts=4096, torque_resolution=0.01, torque_noise=0.005)
FRICTION = Limits(V_max=24.0, friction={"m": 0.02, "L2": 0.5})
IVP_SAMPLES = 200


def _numpy_loop(loop, setup, n):
    """The same sampled-data loop, one numpy step per sample (exact ZOH matrices)."""
    Ac, Bc, Cc, Dc = (m[0] for m in controller_batch(loop, P_GAIN, D_GAIN))
    Phi, Gam = setup.plant_parts["Phi"], setup.plant_parts["Gamma"]
    r = setup.rows
    x, xc = setup.x0.copy(), np.zeros(Ac.shape[0])
    exo = setup.exo
    qt, qT, Vm = setup.q_theta, setup.q_T, setup.V_max
    y = np.empty((n, 2))
    for k in range(n):
        th = math.floor(r["c_theta"] @ x / qt + 0.5) * qt
        T = math.floor((r["c_T"] @ x + exo[3, k]) / qT + 0.5) * qT
        u = np.array([th, T, exo[1, k], exo[2, k]])
        V = Cc[0] @ xc + Dc[0] @ u
        xc = Ac @ xc + Bc @ u
        V = min(max(V, -Vm), Vm)
        y[k] = th, V
        x = Phi @ x + Gam @ np.array([V, exo[0, k]])
    return y


def _ivp_loop(loop, setup, n, friction=None):
    cont = continuous_plant(loop.params.plant)
    A, B = cont.A, cont.B
    Ac, Bc, Cc, Dc = (m[0] for m in controller_batch(loop, P_GAIN, D_GAIN))
    r = setup.rows
    qt, qT, Vm = setup.q_theta, setup.q_T, setup.V_max
    x, xc = setup.x0.copy(), np.zeros(Ac.shape[0])
    exo, Ts = setup.exo, setup.Ts
    sel = [] if friction is None else list(zip(*friction))

    def f(t, z, V, Td):
        dz = A @ z + B[:, 0] * V + B[:, 2] * Td
        for i, col, fc in sel:
            dz -= col * fc * math.tanh(z[i] / 0.01)
        return dz
    for k in range(n):
        th = r["c_theta"] @ x
        T = r["c_T"] @ x + exo[3, k]
        if qt:
            th, T = math.floor(th / qt + 0.5) * qt, math.floor(T / qT + 0.5) * qT
        u = np.array([th, T, exo[1, k], exo[2, k]])
        V = min(max(Cc[0] @ xc + Dc[0] @ u, -Vm), Vm)
        xc = Ac @ xc + Bc @ u
        x = scipy.integrate.solve_ivp(f, (k * Ts, (k + 1) * Ts), x, method="LSODA", rtol=1e-8, atol=1e-10,
                                      args=(V, exo[0, k])).y[:, -1]
    return x


def main() -> int:
    run = Run("bench_simulate.py")
    loop = ClosedLoop(load_params(), basis=False)
    results = {"gains": [P_GAIN, D_GAIN], "cases": {}}
    simulate(loop, P_GAIN, D_GAIN, limits=SAT_QUANT, duration=0.01)       # compile, load

    # (1) saturation + quantisation: exact ZOH
    dur = 20.0
    setup = _Setup(loop, SAT_QUANT, "disturbance-step", 1.0, dur, 0, None)
    n = setup.n
    t_c, sim = best(lambda: simulate(loop, P_GAIN, D_GAIN, limits=SAT_QUANT, duration=dur))
    setup.rtol = 1e-6
    t_loop, _ = best(lambda: _run(loop, setup, P_GAIN, D_GAIN))
    n_np = 20000
    t_np, y_np = best(lambda: _numpy_loop(loop, setup, n_np), repeats=1)
    agree_np = float(np.abs(y_np[:, 0] - sim.theta[:n_np]).max())
    t_ivp, _ = best(lambda: _ivp_loop(loop, setup, IVP_SAMPLES), repeats=1)
    row = {"samples": n, "simulate_s": t_c, "steps_per_s": n / t_c, "c_loop_steps_per_s": n / t_loop,
           "numpy_loop_steps_per_s": n_np / t_np, "numpy_vs_generated_theta_max_diff": agree_np,
           "solve_ivp_steps_per_s": IVP_SAMPLES / t_ivp, "target_steps_per_s": 1e6,
           "saturation_time_s": sim.saturation_time}
    row["ratio_vs_numpy"] = row["steps_per_s"] / row["numpy_loop_steps_per_s"]
    row["ratio_vs_solve_ivp"] = row["steps_per_s"] / row["solve_ivp_steps_per_s"]
    results["cases"]["saturation + quantisation (exact ZOH)"] = row
    print(f"(1) saturation + quantisation, {n} samples: simulate {n / t_c:,.0f} steps/s (C loop alone "
          f"{n / t_loop:,.0f}; target 1,000,000: {'met' if n / t_c >= 1e6 else 'NOT met'}); numpy loop "
          f"{n_np / t_np:,.0f} steps/s ({row['ratio_vs_numpy']:.0f}x); solve_ivp loop {IVP_SAMPLES / t_ivp:,.0f} "
          f"steps/s ({row['ratio_vs_solve_ivp']:,.0f}x); theta numpy vs generated max diff {agree_np:.2g} rad")

    # (2) Coulomb friction: integration between samples, substeps chosen per sample
    dur = 5.0
    t_f, simf = best(lambda: simulate(loop, P_GAIN, D_GAIN, limits=FRICTION, duration=dur))
    setup = _Setup(loop, FRICTION, "disturbance-step", 1.0, dur, 0, None)
    n = setup.n
    sel, col, fc = setup.friction
    t_ivp, _ = best(lambda: _ivp_loop(loop, setup, IVP_SAMPLES, friction=(sel, col.T, fc)), repeats=1)
    row = {"samples": n, "mean_substeps": simf.meta["n_sub"], "max_substeps": simf.meta["n_sub_max"],
           "rtol": simf.meta["rtol"], "simulate_s": t_f, "steps_per_s": n / t_f,
           "solve_ivp_steps_per_s": IVP_SAMPLES / t_ivp, "target_steps_per_s": 1e5}
    row["ratio_vs_solve_ivp"] = row["steps_per_s"] / row["solve_ivp_steps_per_s"]
    results["cases"]["Coulomb friction (integrated)"] = row
    print(f"(2) Coulomb friction, {n} samples, {simf.meta['n_sub']:.1f} substeps per sample on average (at most "
          f"{simf.meta['n_sub_max']}, rtol {simf.meta['rtol']:g}): {n / t_f:,.0f} steps/s (target 100,000: "
          f"{'met' if n / t_f >= 1e5 else 'NOT met'}); solve_ivp loop {IVP_SAMPLES / t_ivp:,.0f} steps/s "
          f"({row['ratio_vs_solve_ivp']:,.0f}x)")
    for name, lim in (("leg friction only (0.5 Nm)", Limits(V_max=24.0, friction={"L2": 0.5})),
                      ("rotor friction only (0.02 Nm)", Limits(V_max=24.0, friction={"m": 0.02}))):
        t_x, sx = best(lambda: simulate(loop, P_GAIN, D_GAIN, limits=lim, duration=dur))
        results["cases"][f"Coulomb friction: {name}"] = {"samples": n, "steps_per_s": n / t_x,
                                                         "mean_substeps": sx.meta["n_sub"]}
        print(f"    {name}: {n / t_x:,.0f} steps/s, {sx.meta['n_sub']:.1f} substeps per sample on average")
    t_r, sr = best(lambda: simulate(loop, P_GAIN, D_GAIN, limits=FRICTION, duration=dur, rtol=1e-4))
    results["cases"]["Coulomb friction, rtol 1e-4"] = {"samples": n, "steps_per_s": n / t_r,
                                                       "mean_substeps": sr.meta["n_sub"],
                                                       "max_rel_diff_torque_vs_rtol_1e-6":
                                                       float(np.abs(sr.torque - simf.torque).max()
                                                             / np.abs(simf.torque).max())}
    print(f"    both at rtol 1e-4: {n / t_r:,.0f} steps/s, {sr.meta['n_sub']:.1f} substeps per sample on average, "
          f"torque within {results['cases']['Coulomb friction, rtol 1e-4']['max_rel_diff_torque_vs_rtol_1e-6']:.1g} "
          "of the rtol 1e-6 run (relative to its peak)")

    # a 100 x 50 batch
    P = np.repeat(np.geomspace(1, 20000, 100), 50)
    D = np.tile(np.linspace(1, 50, 50), 100)
    t0 = time.perf_counter()
    b = simulate_batch(loop, P, D, limits=SAT_QUANT, duration=0.5)
    t_b = time.perf_counter() - t0
    counts = {s: int((b.status == s).sum()) for s in np.unique(b.status)}
    results["batch_100x50"] = {"seconds": t_b, "duration_each_s": 0.5, "status_counts": counts, "target_s": 60}
    print(f"100 x 50 batch (0.5 s each, case 1's limits): {t_b:.2f} s (target 60 s: {'met' if t_b < 60 else 'NOT met'}); {counts}")
    print(f"wrote {run.write('results_simulate.json', results)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
