"""The loop's elements evaluated in one stacked pass (:func:`haa_sym.model.elements.frequency_responses`)
equal the one-by-one :meth:`Element.frequency_response` to the last bit, for every velocity
filter of the registry, and both match numpy's polyval of the same rational functions."""
import numpy as np
import pytest

from haa_sym.explore.state import ViewState, resolve
from haa_sym.model import filters
from haa_sym.model.elements import frequency_responses

def _cases():
    out = [("default", {})]
    for name in filters.names():
        needs = {p.name: ("60" if p.name == "f_c" else "4") for p in filters.get(name).parameters}
        out.append((name, {"velocity_filter": name, **needs}))
    out.append(("N_av=50", {"N_av": "50"}))
    return out


@pytest.mark.parametrize("name,sets", _cases(), ids=[c[0] for c in _cases()])
def test_stacked_equals_one_by_one(name, sets):
    s = ViewState()
    for k, v in sets.items():
        s = s.with_set(k, v)
    loop = resolve(s).loop
    Ts = loop.params.controller.Ts
    # from far below the loop's band to just below Nyquist, where the w basis takes over
    omega = np.concatenate([np.geomspace(1e-3, 0.99 * np.pi / Ts, 300), [np.pi / Ts]])
    els = list(loop.elements.values())
    got = frequency_responses(els, omega, Ts)
    assert len(got) == len(els)
    for e, g in zip(els, got):
        one = e.frequency_response(omega, Ts)
        assert np.array_equal(g, one), e.name
        # and what they compute is the rational function (polyval in z, away from cancellation)
        z = np.exp(1j * omega[omega * Ts > 1e-2] * Ts)
        ref = np.polyval([float(c) for c in e.numerator], z) / np.polyval([float(c) for c in e.denominator], z)
        np.testing.assert_allclose(g[omega * Ts > 1e-2], ref, rtol=1e-9)


def test_empty_and_single():
    loop = resolve(ViewState()).loop
    assert frequency_responses([], [1.0, 2.0], 1e-3) == []
    e = loop.elements["z_delay"]
    np.testing.assert_array_equal(frequency_responses([e], [1.0, 2.0], 1e-3)[0], e.frequency_response([1.0, 2.0], 1e-3))
