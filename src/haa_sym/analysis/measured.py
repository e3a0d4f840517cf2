"""Measured stability points against the model (issue 17): how many experiments the model
agrees with, by a stated rule.

The model's verdict at a measured point is decided exactly, point by point
(:func:`haa_sym.analysis.decide.decide_points`: certified stability, the phase margin by the
options' rule), not read off the map's grid. The rule (docs/uncertainty.md):

* ``stable`` agrees with a model-stable point;
* ``unstable`` agrees with a model-unstable point;
* ``limit_cycle`` agrees with a model-unstable point OR a model-stable point whose phase margin
  is below the threshold (30 deg, ``low_pm``): a sustained oscillation is the linear model's
  instability bounded by a nonlinearity (saturation, friction), or a lightly damped loop kept
  oscillating by them; a limit cycle at a point the model calls well damped disagrees.

Over several configurations (a leg range, an uncertainty box: ``regions --robust``), a point
``agrees`` when SOME configuration predicts the outcome (the experiment ran on one robot whose
values lie somewhere in the range), and ``agrees_all`` when EVERY configuration does (the
stricter count; with one configuration both are the same).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from haa_sym.analysis.decide import decide_points
from haa_sym.errors import ParameterError
from haa_sym.io.measured import OUTCOMES
from haa_sym.loop import ClosedLoop, loop_first

__all__ = ["OUTCOMES", "Agreement", "agreement", "predicts"]


def predicts(outcome, stable, low_pm) -> np.ndarray:
    """Whether a model verdict (``stable``, ``low_pm``: bool arrays) predicts the measured
    ``outcome`` (array of :data:`OUTCOMES`), by the module's rule."""
    outcome = np.asarray(outcome)
    stable, low_pm = np.asarray(stable, bool), np.asarray(low_pm, bool)
    return np.where(outcome == "stable", stable,
                    np.where(outcome == "unstable", ~stable, ~stable | (stable & low_pm)))


@dataclass(frozen=True)
class Agreement:
    """Per measured point (flat arrays): ``agrees`` (some configuration predicts the outcome),
    ``agrees_all`` (every one does), the model's ``stable_all`` / ``stable_any`` and
    ``low_pm_any`` (stable with PM below the threshold at some configuration); ``counts``: per
    outcome and in total, how many points and how many agree (plain data for meta)."""

    P_gain: np.ndarray
    D_gain: np.ndarray
    outcome: np.ndarray
    agrees: np.ndarray
    agrees_all: np.ndarray
    stable_all: np.ndarray
    stable_any: np.ndarray
    low_pm_any: np.ndarray
    counts: dict = field(default_factory=dict)


@loop_first
def agreement(loop, P_gain, D_gain, outcome, *, beta=None, alpha=None, configurations=None) -> Agreement:
    """How the model's verdicts at measured points agree with the measured outcomes.

    Parameters
    ----------
    loop : ClosedLoop
        The model (and options) the experiments are compared with.
    P_gain, D_gain : array_like
        The measured points, Nm/rad and Nms/rad (paired, flat).
    outcome : array_like of str
        One of :data:`OUTCOMES` per point.
    beta, alpha : float, optional
        Inner gains (default the controller's).
    configurations : list of dict, optional
        Plant overrides (a robust region's ``configurations``): the verdict at each; default
        the loop alone.

    Returns
    -------
    Agreement
    """
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    out = np.asarray(outcome).astype(str).ravel()
    if out.size != P.size:
        raise ParameterError(f"outcome: {out.size} values for {P.size} points; allowed: one outcome per point")
    bad = sorted(set(out) - set(OUTCOMES))
    if bad:
        raise ParameterError(f"outcome {str(bad[0])!r}; allowed: one of {list(OUTCOMES)}")
    loops = [loop] if not configurations else \
        [ClosedLoop(loop.params.with_values(**c), loop.options, loop.backend) for c in configurations]
    n = P.size
    any_ok, all_ok = np.zeros(n, bool), np.ones(n, bool)
    stable_all, stable_any, low_any = np.ones(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    for lp in loops:
        d = decide_points(lp, P, D, beta, alpha, passivity=False)
        ok = predicts(out, d.stable, d.low_pm)
        any_ok |= ok
        all_ok &= ok
        stable_all &= d.stable
        stable_any |= d.stable
        low_any |= d.stable & d.low_pm
    counts = {"rule": "stable: model stable; unstable: model unstable; limit_cycle: model unstable or stable with "
                      "PM < 30 deg" + ("; agrees: some configuration predicts it, agrees_all: every one"
                                       if len(loops) > 1 else ""),
              "configurations": len(loops), "points": int(n), "agree": int(any_ok.sum()),
              "agree_all": int(all_ok.sum())}
    for o in OUTCOMES:
        sel = out == o
        counts[o] = {"points": int(sel.sum()), "agree": int(any_ok[sel].sum()), "agree_all": int(all_ok[sel].sum())}
    return Agreement(P, D, out, any_ok, all_ok, stable_all, stable_any, low_any, counts)
