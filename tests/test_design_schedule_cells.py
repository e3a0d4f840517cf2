"""The schedule's cell check converges in a few passes (issue 26, item 12): a synthetic boundary
that needs the corner values lowered by about a hundred steps of the beta grid is met by
bisection, not one step a pass, and every cell left safe holds on its sub-grid at its final
corners (the guarantee the C lookup relies on)."""
import numpy as np

from haa_sym.design.schedule import _check_cells, beta_grid

P = np.geomspace(1.0, 1000.0, 6)
D = np.linspace(1.0, 50.0, 5)
N_SUB = 4


def limit(P, D):
    """The largest safe beta at (P_gain, D_gain): a smooth surface far below the range's top."""
    return 0.2 + 0.004 * D * np.log(P + 1.0)


class Rule:
    """A runner that decides the cell check's point tasks by :func:`limit` (beta <= limit holds;
    a hole at one corner's cell makes it hold nowhere), counting the task lists (passes)."""

    def __init__(self):
        self.passes, self.labels = 0, []

    def run(self, fn, tasks, label, unit="task"):
        self.passes += 1
        self.labels.append(label)
        return [np.asarray(b <= limit(Ps, Ds) * (1 + 1e-12)) & ~((Ps > 500) & (Ds > 40))
                for _, _, Ps, Ds, b, _, _, _ in tasks]


def test_cell_check_bisects_the_corner_values_and_keeps_its_guarantee():
    fine, _ = beta_grid((0.1, 8.0), 0.02)
    K0 = np.full((P.size, D.size), fine.size - 1)
    alpha = np.full(K0.shape, 0.94)
    runner = Rule()
    out = _check_cells(runner, None, [{}], P, D, fine, K0, alpha, ("stable",), None, N_SUB)
    K, safe = out[0], out[1]
    drop = K0 - K
    assert drop.max() > 100, "the synthetic boundary must need a long way down"
    assert runner.passes <= 20, f"{runner.passes} passes (one step a pass needs > 100)"
    assert runner.labels[0] == "schedule: cells (pass 1)"
    # the guarantee, recomputed here: every safe cell holds at both bracketing grid values of
    # every interpolated beta of its 5 x 5 sub-grid; the hole's cell has no safe gain
    s = np.arange(N_SUB + 1) / N_SUB
    t, u = (x.ravel() for x in np.meshgrid(s, s, indexing="ij"))
    assert not safe[-1, -1] and safe.sum() == safe.size - 1
    for i, j in np.argwhere(safe):
        c = fine[K[[i, i + 1, i, i + 1], [j, j, j + 1, j + 1]]]
        b = (1 - t) * (1 - u) * c[0] + t * (1 - u) * c[1] + (1 - t) * u * c[2] + t * u * c[3]
        Ps = P[i] * (P[i + 1] / P[i]) ** t
        Ds = D[j] + u * (D[j + 1] - D[j])
        khi = np.searchsorted(fine, b * (1 - 1e-12))
        assert np.all(fine[khi] <= limit(Ps, Ds) * (1 + 1e-12)), (i, j)
    # and not lowered much below what the boundary allows: within 3 grid steps of the lowest
    # limit on the cells a point is a corner of
    for i in range(P.size):
        for j in range(D.size):
            near = [limit(P[a], D[b]) for a in (i - 1, i, i + 1) for b in (j - 1, j, j + 1)
                    if 0 <= a < P.size and 0 <= b < D.size]
            if (i, j) != (P.size - 1, D.size - 1) and safe[max(i - 1, 0):i + 1, max(j - 1, 0):j + 1].any():
                assert fine[K[i, j]] >= min(near) / 1.02 ** 3, (i, j, fine[K[i, j]], min(near))


class Band(Rule):
    """Feasibility not monotone in beta (as passivity can be): safe at the range's top and at
    low beta, unsafe in between, and unsafe at the top in one corner cell. Lowering that cell
    makes its neighbours interpolate through the unsafe band, and theirs theirs: a chain."""

    def run(self, fn, tasks, label, unit="task"):
        self.passes += 1
        return [np.asarray(((b >= 7.0) & ~((Ps < 3.0) & (Ds < 10.0))) | (b <= 3.0))
                for _, _, Ps, Ds, b, _, _, _ in tasks]


def test_a_chain_of_failing_cells_ends_after_cell_rounds_and_keeps_the_guarantee():
    fine, _ = beta_grid((0.1, 8.0), 0.02)
    K0 = np.full((P.size, D.size), fine.size - 1)
    alpha = np.full(K0.shape, 0.94)
    unbounded, bounded = Band(), Band()
    K_u, safe_u = _check_cells(unbounded, None, [{}], P, D, fine, K0, alpha, ("passive",), None, N_SUB)[:2]
    K_b, safe_b, _, _, given_up, passes = _check_cells(bounded, None, [{}], P, D, fine, K0, alpha, ("passive",),
                                                       None, N_SUB, 3)
    # unbounded, the chain lowers every cell to the low band (cell by cell); bounded, it stops
    assert np.all(fine[K_u] <= 3.0) and safe_u.all()
    assert passes == bounded.passes < unbounded.passes / 2
    assert given_up > 0 and safe_b.sum() > 0
    s = np.arange(N_SUB + 1) / N_SUB
    t, u = (x.ravel() for x in np.meshgrid(s, s, indexing="ij"))
    for i, j in np.argwhere(safe_b):          # every cell left safe holds at its final corners
        c = fine[K_b[[i, i + 1, i, i + 1], [j, j, j + 1, j + 1]]]
        b = (1 - t) * (1 - u) * c[0] + t * (1 - u) * c[1] + (1 - t) * u * c[2] + t * u * c[3]
        Ps, Ds = P[i] * (P[i + 1] / P[i]) ** t, D[j] + u * (D[j + 1] - D[j])
        for k in (np.searchsorted(fine, b * (1 - 1e-12)), np.searchsorted(fine, b * (1 + 1e-12), "right") - 1):
            fb = fine[np.clip(k, 0, fine.size - 1)]
            assert np.all(((fb >= 7.0) & ~((Ps < 3.0) & (Ds < 10.0))) | (fb <= 3.0)), (i, j)


class AlphaRule(Rule):
    """As :class:`Rule`, with a limit that grows with alpha, and every alpha a task was asked at
    recorded: where the corners' alphas differ the cell check interpolates alpha too."""

    def __init__(self):
        super().__init__()
        self.alphas = set()

    def run(self, fn, tasks, label, unit="task"):
        self.passes += 1
        self.alphas.update(a for *_, a, _, _ in tasks)
        return [np.asarray(b <= limit(Ps, Ds) * (1 + 0.5 * (a - 1.0)) * (1 + 1e-12))
                for _, _, Ps, Ds, b, a, _, _ in tasks]


def test_interpolated_alphas_are_decided_at_their_own_values_and_keep_the_guarantee():
    """The cell check names each decision by (beta, alpha, sub-grid indices): with alpha varying
    from corner to corner (an alpha-scheduled table), the sub-points' alphas are bilinear in the
    corners' and every safe cell holds at them, recomputed here."""
    fine, _ = beta_grid((0.1, 8.0), 0.02)
    K0 = np.full((P.size, D.size), fine.size - 1)
    alpha = 0.6 + 0.1 * np.add.outer(np.arange(P.size), np.arange(D.size))      # 0.6 .. 1.4
    runner = AlphaRule()
    K, safe = _check_cells(runner, None, [{}], P, D, fine, K0, alpha, ("stable",), None, N_SUB)[:2]
    assert safe.all() and np.any(K < K0)
    s = np.arange(N_SUB + 1) / N_SUB
    t, u = (x.ravel() for x in np.meshgrid(s, s, indexing="ij"))
    asked = set()
    for i, j in np.argwhere(safe):
        ci, cj = [i, i + 1, i, i + 1], [j, j, j + 1, j + 1]
        w = np.stack([(1 - t) * (1 - u), t * (1 - u), (1 - t) * u, t * u], axis=1)
        b, a = w @ fine[K[ci, cj]], w @ alpha[ci, cj]
        asked.update(a.tolist())
        Ps, Ds = P[i] * (P[i + 1] / P[i]) ** t, D[j] + u * (D[j + 1] - D[j])
        for k in (np.searchsorted(fine, b * (1 - 1e-12)), np.searchsorted(fine, b * (1 + 1e-12), "right") - 1):
            fb = fine[np.clip(k, 0, fine.size - 1)]
            assert np.all(fb <= limit(Ps, Ds) * (1 + 0.5 * (a - 1.0)) * (1 + 1e-12)), (i, j)
    # the final corners' sub-points' alphas were all asked (to the last bit), and more than the
    # corners' own values: interpolated ones
    assert asked <= runner.alphas and len(runner.alphas) > np.unique(alpha).size
