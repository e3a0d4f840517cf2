"""``--input torque_ref``: the file's torque loop closed around the plant, with exact derivatives.

The closed loop is the loop's own explicit realisation (:func:`haa_sym.loop.statespace.closed_loop_batch`,
cut at the torque reference, so the impedance loop is open and ``r`` is the torque reference):
the controller (PI of Eq. 7, velocity compensation of Eq. 6, its filters, the delay) at the
file's ``Ts``, around the ZOH-sampled plant. Its matrices are polynomials of degree <= 3 in the
sampled plant's (Phi, Gamma, C) and VC0 (products such as Gamma VC C), so their derivative
along a parameter direction is the five-point stencil
f'(0) = [8 (f(h) - f(-h)) - (f(2h) - f(-2h))] / (12 h), exact for polynomials up to degree 4
(only rounding remains), with the plant's derivatives from :mod:`haa_sym.fit.model`.
"""
from __future__ import annotations

import numpy as np

from haa_sym.fit.model import Sampled, output_rows, plant_derivatives, sample, PlantModel
from haa_sym.loop import ClosedLoop
from haa_sym.loop.plant import DiscretePlant
from haa_sym.loop.statespace import closed_loop_batch

__all__ = ["torque_loop_model"]


class _LoopWithPlant:
    """A closed loop's controller with another sampled plant and VC0 (what closed_loop_batch reads)."""

    def __init__(self, loop, plant: DiscretePlant):
        self.params, self.options, self.elements = loop.params, loop.options, loop.elements
        self.plant = plant
        # the structure's constants (haa_sym.model.structures), VC0 from the fitted plant when
        # the structure compensates; P_m0, the PI's gain on the measured torque
        self.const = np.array([loop.const[0], loop.const[1],
                               plant.VC0 if loop.structure.velocity_compensation else 0.0])
        self.P_m0 = loop.P_m0
        self.torque_output = loop.torque_output

    def plant_output(self, name):
        return self.plant.output_names.index(name)


_LOOPS: dict = {}


def _loop(params, options):
    """A loop of the controller and options (its elements cost rational arithmetic: built once
    per controller; the plant it was built with is replaced by :class:`_LoopWithPlant`)."""
    key = (repr(params.controller), repr(options), params.plant.topology.fingerprint)
    if key not in _LOOPS:
        if len(_LOOPS) > 16:
            _LOOPS.clear()
        _LOOPS[key] = ClosedLoop(params, options, basis=False)
    return _LOOPS[key]


def torque_loop_model(params, keys, inputs, outputs, options=None) -> Sampled:
    """The closed torque loop from ``torque_ref`` (and ``T_dist``) to ``outputs`` at the file's Ts."""
    loop = _loop(params, options)
    loop.require("voltage", "identify (the torque loop closed around the fitted voltage-driven plant)")
    top = params.plant.topology
    A, B, C, dA, dB, dC, VC0, dVC0 = plant_derivatives(params.plant, keys, vc0=True)
    Ts = params.controller.Ts
    s = sample(PlantModel(A, B, C, np.zeros((C.shape[0], 3)), dA, dB, dC, np.zeros((len(keys), C.shape[0], 3))), Ts)
    names = (top.state_names, top.input_names, top.output_names)

    def closed(h, j):
        if j is None:
            Phi, Gam, Cm, vc = s.Phi, s.Gamma, s.C, VC0
        else:
            Phi, Gam, Cm, vc = (s.Phi + h * s.dPhi[j], s.Gamma + h * s.dGamma[j], s.C + h * s.dC[j],
                                VC0 + h * dVC0[j])
        plant = DiscretePlant(Phi, Gam, Cm, Ts, float(vc), *names)
        Acl, Bcl, _, _ = closed_loop_batch(_LoopWithPlant(loop, plant), 0.0, 0.0, cut="T_ref")
        cols = [1] + ([0] if "T_dist" in inputs else [])
        return Acl[0], Bcl[0][:, cols]
    Acl, Bcl = closed(0.0, None)
    p = len(keys)
    dAcl, dBcl = np.zeros((p,) + Acl.shape), np.zeros((p,) + Bcl.shape)
    values = params.plant.as_dict()
    for j, k in enumerate(keys):
        h = values[k]
        fs = {m: closed(m * h, j) for m in (-2, -1, 1, 2)}
        for i, target in enumerate((dAcl, dBcl)):
            target[j] = (8 * (fs[1][i] - fs[-1][i]) - (fs[2][i] - fs[-2][i])) / (12 * h)
    n_cl, n = Acl.shape[0], A.shape[0]
    rows = output_rows(top, outputs)
    Cout, dCout = np.zeros((len(rows), n_cl)), np.zeros((p, len(rows), n_cl))
    for i, (kind, j) in enumerate(rows):
        if kind == "y":
            Cout[i, :n], dCout[:, i, :n] = C[j], dC[:, j]
        else:
            Cout[i, j] = 1.0
    m = Bcl.shape[1]
    return Sampled(Acl, Bcl, Cout, np.zeros((len(rows), m)), dAcl, dBcl, dCout, np.zeros((p, len(rows), m)), Ts)
