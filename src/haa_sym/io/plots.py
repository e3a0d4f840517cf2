"""Figures (matplotlib, no computation): region maps as in Figs. 8-11, Z phase as in Fig. 12,
torque steps as in Fig. 7. Every function takes computed data and returns the Figure."""
from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import patheffects  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from haa_sym.errors import ParameterError  # noqa: E402
from haa_sym.io.outputs import transaction  # noqa: E402
from haa_sym.io.logs import OUTPUT_UNITS  # noqa: E402

__all__ = ["plot_region", "plot_region_panels", "plot_corrected_phase", "plot_steps",
           "plot_contact", "gains_text", "plot_torque_bandwidth", "STYLE", "plot_describing", "save_figure", "check_title", "plot_identify"]

# Figs. 8-11: white stable, light grey stable with PM < 30 deg, dark unstable.
REGION_COLORS = ListedColormap(["#ffffff", "#c8c8c8", "#3a3a3a"])


# Where a result is infeasible (no robust gain, fails a requirement): one colour in every panel.
INFEASIBLE_COLOR = "#9a9a9a"

# One visual language for every figure: the measured / simulated trace black, a reference signal
# tab:orange, what is unstable or exceeds a bound tab:red, a derived second signal tab:blue, the
# recorded data under a model wide light grey, a model before a change (fit, tuning) red dashed
# and after it blue, reference levels mid grey; a figure's title 11 pt (smaller when it has
# several lines), a panel's 9 pt, legends 8 pt, below the axes ("outside lower center") when
# they list more than one panel's curves.
STYLE = {"measured": "k", "prediction": "tab:orange", "unstable": "tab:red", "second": "tab:blue",
         "data": "0.75", "reference": "0.6", "before": "tab:red", "after": "tab:blue", "title_size": 11,
         "panel_title_size": 9, "legend_size": 8, "legend_loc": "outside lower center"}
# The torque-bandwidth contours (rad/s) of plot_torque_bandwidth, marked on its colour bar.
BANDWIDTH_CONTOURS = (10, 20, 50, 100, 200)


def _wrap(title: str, width_in: float, size: float = 10) -> str:
    """``title`` with each line wrapped to the width of a figure ``width_in`` inches wide at font
    size ``size`` (about 12 characters an inch at 10 pt); lines already short are kept as given."""
    n = max(30, int(width_in * 120 / size))
    return "\n".join(textwrap.fill(line, n) if len(line) > n else line for line in title.split("\n"))


def _title_size(title: str, size: float) -> float:
    """A smaller font for a title of several lines (a name and what differs from the file)."""
    return size - 2 if "\n" in title else size


def _plain_ticks(cbar) -> None:
    """Colour-bar tick labels as plain numbers (2, 5, 8 rather than 2x10^0 on a log scale)."""
    from matplotlib.ticker import FuncFormatter
    fmt = FuncFormatter(lambda v, _: f"{v:g}")
    for axis in (cbar.ax.yaxis, cbar.ax.xaxis):
        axis.set_major_formatter(fmt)
        axis.set_minor_formatter(fmt)


def _edges(x: np.ndarray, log: bool) -> np.ndarray:
    if x.size == 1:
        return np.array([x[0] * 0.9, x[0] * 1.1]) if log else np.array([x[0] - 0.5, x[0] + 0.5])
    v = np.log(x) if log else x
    mid = (v[1:] + v[:-1]) / 2
    e = np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])
    return np.exp(e) if log else e


def _gain_axes(ax, logP: bool) -> None:
    """The impedance-gain plane's axes: P_gain (log when every value is > 0) and D_gain."""
    if logP:
        ax.set_xscale("log")
    ax.set_xlabel("P_gain (Nm/rad)")
    ax.set_ylabel("D_gain (Nms/rad)")


def plot_region(m, ax=None, title: str | None = None, passivity: bool = True, boundary=None, measured=None):
    """Draw one :class:`haa_sym.analysis.regions.RegionMap` on ``ax`` (log P_gain, linear D_gain), with
    the exact curves (:func:`haa_sym.analysis.boundaries.stability.boundaries`) over it when given,
    and measured points (``measured``, see :func:`draw_measured`) over both."""
    fig = None
    if ax is None:
        fig, ax = plt.subplots(figsize=(4.6, 4.4), layout="constrained")
    cls = np.where(~m.stable, 2, np.where(m.low_pm, 1, 0))
    logP = bool(np.all(m.P_gain > 0))
    ax.pcolormesh(_edges(m.P_gain, logP), _edges(m.D_gain, False), cls.T, cmap=REGION_COLORS,
                  vmin=-0.5, vmax=2.5, shading="flat", rasterized=True)
    if passivity and m.P_gain.size > 1 and m.D_gain.size > 1:
        if m.passive.any() and (~m.passive).any() and boundary is None:   # else: the exact curve
            ax.contour(m.P_gain, m.D_gain, m.passive.T.astype(float), levels=[0.5], colors="tab:blue",
                       linewidths=1.0, linestyles="--")
        not_passive = (m.stable & ~m.passive).T.astype(float)
        if not_passive.any():                   # also when no point is passive (then all hatched)
            cs = ax.contourf(m.P_gain, m.D_gain, not_passive, levels=[0.5, 1.5], colors="none",
                             hatches=["////"])
            cs.set_edgecolor("tab:blue")
            cs.set_linewidth(0)
    if boundary is not None:
        plot_boundary(boundary, ax)
        ax.set_xlim(_edges(m.P_gain, logP)[[0, -1]])
        ax.set_ylim(_edges(m.D_gain, False)[[0, -1]])
    points = draw_measured(ax, measured, _edges(m.P_gain, logP)[[0, -1]], _edges(m.D_gain, False)[[0, -1]])
    _gain_axes(ax, logP)
    if title:
        w = ax.figure.get_figwidth() / (len(ax.figure.axes) or 1)
        ax.set_title(_wrap(title, w), fontsize=_title_size(title, 10))
    if fig is not None:
        extra = curve_legend(boundary) if boundary is not None else []
        fig.legend(handles=_region_legend(boundary is None) + extra + points, loc="outside lower center", ncol=2,
                   fontsize=7)
    return fig or ax.figure


_CURVE_STYLES = {"complex": dict(color="tab:red", lw=1.4), "z=1": dict(color="tab:orange", lw=1.4, ls="-."),
                 "z=-1": dict(color="tab:purple", lw=1.4, ls=":"),
                 "pm": dict(color="tab:green", lw=1.1, ls="--"),
                 "passivity": dict(color="tab:cyan", lw=1.2, ls="-"),
                 # where the judged frequency range (omega_min to Nyquist) ends, not |phase Z| = 90
                 # deg: the same colour (it bounds the same passive set), dash-dot-dot
                 "range edge": dict(color="tab:cyan", lw=1.6, ls=(0, (6, 2, 1.5, 2, 1.5, 2)))}

# haa_sym.analysis.boundaries.passivity's kinds of a range edge -> which edge
_RANGE_EDGES = {"passivity (omega_min)": "omega_min", "passivity (Nyquist)": "Nyquist"}


def _curve_label(kind: str) -> tuple[str, str]:
    """(style key, legend label) of a curve kind."""
    if kind.startswith("pm="):
        return "pm", f"phase margin {kind[3:]} deg"
    if kind in _RANGE_EDGES:
        return "range edge", f"edge of the judged frequency range ({_RANGE_EDGES[kind]})"
    if kind.startswith("passivity"):
        return "passivity", "passivity boundary (|phase Z| = 90 deg)"
    return kind, f"stability boundary ({kind})"


def _drawn(curve) -> bool:
    """Whether a curve has a point to draw (a legend names only what is drawn)."""
    P, D = np.asarray(curve.P_gain, float), np.asarray(curve.D_gain, float)
    return bool(np.any(np.isfinite(P) & np.isfinite(D)))


def plot_boundary(boundary, ax=None, title: str | None = None):
    """Draw the curves of a :class:`haa_sym.analysis.boundaries.stability.Boundaries` (stability, phase margin,
    passivity) or :class:`haa_sym.analysis.boundaries.stability.StabilityBoundary` (on ``ax``: over a map)."""
    fig = None
    st = getattr(boundary, "stability", boundary)
    if ax is None:
        fig, ax = plt.subplots(figsize=(4.6, 4.4), layout="constrained")
        ax.set_xlabel("P_gain (Nm/rad)")
        ax.set_ylabel("D_gain (Nms/rad)")
        lo, hi = st.meta.get("P_range", (0, 1))
        if lo > 0:
            ax.set_xscale("log")
        ax.set_xlim(lo, hi)
        ax.set_ylim(*st.meta.get("D_range", (0, 1)))
    seen = set()
    for c in boundary.curves:
        if not _drawn(c):
            continue
        key, label = _curve_label(c.kind)
        ax.plot(c.P_gain, c.D_gain, label=None if label in seen else label, **_CURVE_STYLES[key])
        seen.add(label)
    if title:
        ax.set_title(_wrap(title, ax.figure.get_figwidth()), fontsize=_title_size(title, 10))
    if fig is not None and seen:
        ax.legend(fontsize=7)
    return fig or ax.figure


def curve_legend(boundary) -> list:
    """Legend handles for the curve kinds drawn by :func:`plot_boundary`."""
    out, seen = [], set()
    for c in boundary.curves:
        key, label = _curve_label(c.kind)
        if label not in seen and _drawn(c):
            seen.add(label)
            out.append(plt.Line2D([], [], label=label, **_CURVE_STYLES[key]))
    return out


# The paper's Figs. 8-11 mark experiments with crosses (unstable) and squares (stable); it has no
# limit cycles, so an open triangle marks those. The colour says whether the model agrees
# (haa_sym.analysis.measured's rule); a white outline keeps a marker visible on the dark region.
MEASURED_MARKERS = {"stable": ("s", "stable (measured, square)"), "unstable": ("x", "unstable (measured, cross)"),
                    "limit_cycle": ("^", "limit cycle (measured, triangle)")}
MEASURED_COLORS = {True: ("#0060ff", "agrees with the model"), False: ("#e00000", "disagrees with the model")}


def draw_measured(ax, measured, P_lim, D_lim) -> list:
    """Measured points on ``ax`` with the paper's symbols (:data:`MEASURED_MARKERS`), coloured by
    agreement (:data:`MEASURED_COLORS`); ``measured``: plain data ``{"P_gain", "D_gain",
    "outcome", "agrees"}`` (flat arrays) and optionally ``"configurations"`` (how many the verdict
    spans: above 1 the legend says "at some configuration") or None. Points outside ``P_lim`` x ``D_lim`` are not
    drawn (the axes keep the map's extent). Returns the legend handles (empty without points)."""
    if measured is None:
        return []
    P, D = np.asarray(measured["P_gain"], float), np.asarray(measured["D_gain"], float)
    out, agrees = np.asarray(measured["outcome"]).astype(str), np.asarray(measured["agrees"], bool)
    inside = (P >= P_lim[0]) & (P <= P_lim[1]) & (D >= D_lim[0]) & (D <= D_lim[1])
    halo = [patheffects.withStroke(linewidth=3.0, foreground="white")]
    handles = []
    for o, (marker, label) in MEASURED_MARKERS.items():
        for ok, (color, _) in MEASURED_COLORS.items():
            sel = inside & (out == o) & (agrees == ok)
            if sel.any():
                # clip_on=False: a point on the map's edge (a grid's end value) is drawn whole
                ax.plot(P[sel], D[sel], ls="none", marker=marker, ms=6, mfc="none", mec=color, mew=1.6,
                        path_effects=halo, zorder=5, clip_on=False)
        if (out == o).any():
            handles.append(plt.Line2D([], [], ls="none", marker=marker, ms=6, mfc="none", mec="k", mew=1.4,
                                      label=label))
    # over several configurations a point agrees when SOME configuration predicts it
    # (analysis.measured): the legend must not read as "the model" of one configuration
    scope = {True: " at some configuration", False: " at every configuration"} \
        if measured.get("configurations", 1) > 1 else {True: "", False: ""}
    for ok, (color, label) in MEASURED_COLORS.items():
        if (agrees == ok).any():
            handles.append(Patch(facecolor=color, edgecolor=color, label=f"{label}{scope[ok]} (marker colour)"))
    return handles


def _region_legend(grid_contour: bool = True):
    return [Patch(facecolor="#ffffff", edgecolor="k", label="stable, PM >= 30 deg"),
            Patch(facecolor="#c8c8c8", edgecolor="k", label="stable, PM < 30 deg"),
            Patch(facecolor="#3a3a3a", edgecolor="k", label="unstable")] + \
        ([plt.Line2D([], [], color="tab:blue", ls="--", label="passivity boundary (grid)")] if grid_contour else []) + \
        [Patch(facecolor="none", edgecolor="tab:blue", hatch="////", label="stable, not passive")]


#: Markers of the nonlinear classes (haa_sym.analysis.oscillation.VERDICTS) over a map.
NONLINEAR_MARKERS = {"converging": dict(marker=".", color="tab:green", ms=3),
                     "limit cycle": dict(marker="o", mfc="none", color="tab:red", ms=5),
                     "saturating": dict(marker="s", mfc="none", color="tab:purple", ms=5),
                     "growing": dict(marker="x", color="k", ms=5),
                     "undecided": dict(marker="d", mfc="none", color="tab:orange", ms=5),
                     "diverged": dict(marker="+", color="tab:red", ms=6),
                     "forced response": dict(marker="v", mfc="none", color="tab:gray", ms=5)}


def plot_nonlinear_region(m, P_gain, D_gain, class_names, title: str | None = None, boundary=None,
                          max_markers: int = 60):
    """The linear map ``m`` (:func:`plot_region`, with the exact curves ``boundary``) and over it
    the nonlinear class of each gain point (``class_names`` (n_P, n_D) strings on the axes
    ``P_gain``, ``D_gain``), one marker per point of at most ``max_markers`` x ``max_markers``
    evenly strided points (denser grids would hide the map)."""
    fig, ax = plt.subplots(figsize=(5.2, 5.0), layout="constrained")
    plot_region(m, ax, title, boundary=boundary)
    P, D, names = np.asarray(P_gain), np.asarray(D_gain), np.asarray(class_names)
    sp, sd = max(1, -(-P.size // max_markers)), max(1, -(-D.size // max_markers))
    PP, DD = np.meshgrid(P[::sp], D[::sd], indexing="ij")
    sub = names[::sp, ::sd]
    handles = []
    for name, style in NONLINEAR_MARKERS.items():
        pick = sub == name
        n_all = int((names == name).sum())
        line, = ax.plot(PP[pick], DD[pick], ls="none", **style,
                        label=f"simulated: {name} ({n_all})")
        if n_all:
            handles.append(line)
    extra = curve_legend(boundary) if boundary is not None else []
    fig.legend(handles=_region_legend(boundary is None) + extra + handles, loc="outside lower center", ncol=2,
               fontsize=7)
    return fig


def plot_region_panels(maps, titles, suptitle: str = "", boundaries=None):
    """A row of region maps (one paper figure) with the legend of Figs. 8-11, and each panel's
    exact curves (:func:`haa_sym.analysis.boundaries.stability.boundaries`, one per map) over it when given."""
    fig, axes = plt.subplots(1, len(maps), figsize=(3.6 * len(maps), 3.4), squeeze=False,
                             constrained_layout=True)
    boundaries = boundaries or [None] * len(maps)
    for ax, m, t, b in zip(axes[0], maps, titles, boundaries):
        plot_region(m, ax, t, boundary=b)
    extra, seen = [], set()
    for b in boundaries:
        for h in (curve_legend(b) if b is not None else []):
            if h.get_label() not in seen:
                seen.add(h.get_label())
                extra.append(h)
    fig.legend(handles=_region_legend(not extra) + extra, loc="outside lower center",
               ncol=5 if len(maps) >= 3 else 3, fontsize=8)
    if suptitle:
        fig.suptitle(_wrap(suptitle, 3.6 * len(maps)), fontsize=_title_size(suptitle, 11))
    return fig


def plot_corrected_phase(curves, title: str = ""):
    """Corrected phase of Z(z) (Fig. 12): ``curves`` = [(omega, phase_deg, label), ...]."""
    fig, ax = plt.subplots(figsize=(6.4, 3.6), constrained_layout=True)
    for (w, ph, label), color in zip(curves, ("tab:red", "tab:blue", "tab:green", "tab:orange")):
        ax.semilogx(w, ph, color=color, label=label)
    for y in (90, -90):
        ax.axhline(y, color="k", lw=0.8)
    ax.set_xlabel("omega (rad/s)")
    ax.set_ylabel("corrected phase of Z (deg)")
    ax.set_ylim(-180, 180)
    ax.set_yticks(range(-180, 181, 45))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(_wrap(title, 6.4), fontsize=_title_size(title, 10))
    return fig


def plot_steps(panels, title: str = "", ylabel: str = "T_l (Nm)"):
    """Torque steps (Fig. 7): ``panels`` = [(panel_title, [(StepResponse, label, linestyle)])];
    ``ylabel`` names the torque the loop measures, with its unit (the paper's T_l by default)."""
    fig, axes = plt.subplots(len(panels), 1, figsize=(6.4, 2.8 * len(panels) + (0.6 if title else 0)),
                             sharex=True, constrained_layout=True, squeeze=False)
    for ax, (ptitle, lines) in zip(axes[:, 0], panels):
        for s, label, ls in lines:
            ax.plot(s.t, s.T, ls, color="k", label=label)
        ax.axhline(1.0, color="0.6", lw=0.8)
        ax.set_ylabel(ylabel)
        ax.set_title(ptitle, fontsize=10)
        ax.legend(fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("t (s)")
    if title:
        fig.suptitle(_wrap(title, 6.4), fontsize=_title_size(title, 11))
    return fig


def gains_text(P_gain: float, D_gain: float, beta: float | None = None, alpha: float | None = None) -> str:
    """The gains a figure was computed at, as its title says them: ``P_gain = 200 Nm/rad, D_gain
    = 10 Nms/rad, beta = 1, alpha = 0.94``; both impedance gains 0 is the torque loop alone."""
    text = f"P_gain = {P_gain:g} Nm/rad, D_gain = {D_gain:g} Nms/rad"
    if P_gain == 0 and D_gain == 0:
        text = f"torque loop alone ({text}: impedance loop open)"
    return text + "".join(f", {k} = {v:g}" for k, v in (("beta", beta), ("alpha", alpha)) if v is not None)


def plot_contact(K, rho, paper_range=None, unstable=(), key: str = "K_L2", excess=None,
                 not_passive=(), tol: float | None = None, title: str = "", gains: str | None = None,
                 measure: str = "phase_excess_deg"):
    """Spectral radius of the loop against the environment stiffness, with the exact ends of the
    unstable intervals (:func:`haa_sym.analysis.contact.contact_intervals`) and the paper's range; with
    ``excess`` (deg, NaN where unstable) a second panel: the phase excess of Z beyond +-90 deg,
    the tolerance ``tol`` and the exact ends of the stable, non-passive intervals; with
    ``measure = "dissipation_deficit"`` the panel is the exact test's deficit (dimensionless)
    instead. ``gains`` (:func:`gains_text`): the gains the scan was made at, a line of the title."""
    exact = measure == "dissipation_deficit"
    unit = "" if exact else " deg"
    title = "\n".join(x for x in (title, f"gains: {gains}" if gains else "") if x)
    two = excess is not None
    fig, axes = plt.subplots(2 if two else 1, 1, figsize=(6.4, 5.6 if two else 3.2), sharex=True,
                             constrained_layout=True, squeeze=False)
    ax = axes[0, 0]
    ax.semilogx(K, rho, color="k")
    ax.axhline(1.0, color="tab:red", lw=0.8, label="|z| = 1")
    if paper_range:
        ax.axvspan(*paper_range, color="tab:orange", alpha=0.2, label="paper: unstable")
    for i, (lo, hi) in enumerate(unstable):
        for k in (lo, hi):
            ax.axvline(k, color="tab:blue", lw=0.8, ls="--", label=None if i or k == hi else "computed: interval ends")
    ax.set_ylabel("spectral radius (-)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    if two:
        ax = axes[1, 0]
        ax.semilogx(K, excess, color="k", label="stable: exact dissipation deficit -min mu" if exact
                    else "stable: worst |phase of Z| - 90 deg")
        # symmetric log: the passive side sits at rounding level (Z touches -90 deg at Nyquist),
        # the non-passive side spans decades up to 90 deg
        lin = tol if tol else 1e-3
        ax.set_yscale("symlog", linthresh=lin)
        if tol is not None:
            ax.axhline(tol, color="tab:red", lw=0.8, label=f"tolerance {tol:g}{unit}")
        for i, (lo, hi) in enumerate(unstable):
            ax.axvspan(lo, hi, color="0.85", label=None if i else "unstable")
        inner = [k for iv in not_passive for k in iv if K[0] < k < K[-1]]
        for i, (lo, hi) in enumerate(not_passive):
            ax.axvspan(lo, hi, color="tab:purple", alpha=0.12, label=None if i else "stable, not passive")
        for i, k in enumerate(inner):
            ax.axvline(k, color="tab:purple", lw=0.8, ls="--", label=None if i else "computed: interval ends")
        ax.set_ylabel("dissipation deficit (-)" if exact else "phase excess of Z (deg)")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    axes[-1, 0].set_xlabel(f"environment stiffness {key} (Nm/rad)")
    if title:
        fig.suptitle(_wrap(title, 6.4), fontsize=_title_size(title, 11))
    return fig


def plot_torque_bandwidth(panels, title: str = ""):
    """Torque bandwidth over (beta, alpha), one panel per ``(label, beta, alpha, bandwidth,
    stable)``: colour the bandwidth on a log scale (dark: low, bright: high), white contours at
    :data:`BANDWIDTH_CONTOURS` marked on the colour bar (labels on the map overlapped where the
    contours bunch at the stability cliff), cells whose torque loop is unstable hatched red (their
    bandwidth means nothing). The legend has the hatch only when a cell is hatched; a panel
    without one says so in its title."""
    from matplotlib.ticker import FuncFormatter
    fig, axes = plt.subplots(1, len(panels), figsize=(4.4 * len(panels), 3.9), squeeze=False,
                             constrained_layout=True)
    for ax, (label, B, A, bw, stable) in zip(axes[0], panels):
        with np.errstate(divide="ignore", invalid="ignore"):
            logbw = np.log10(bw).T
        cs = ax.contourf(B, A, logbw, levels=20, cmap="viridis")
        lo, hi = cs.get_clim()
        levels = [v for v in np.log10(BANDWIDTH_CONTOURS) if lo < v < hi]
        cb = fig.colorbar(cs, ax=ax, label="torque bandwidth (rad/s, log scale)")
        if levels:
            cl = ax.contour(B, A, logbw, levels=levels, colors="w", linewidths=0.6)
            cb.add_lines(cl)
        if (~stable).any():
            hs = ax.contourf(B, A, (~stable).T.astype(float), levels=[0.5, 1.5], colors="none", hatches=["xxx"])
            hs.set_edgecolor(STYLE["unstable"])
            hs.set_linewidth(0)
        nice = [np.log10(m * 10.0 ** k) for k in range(-3, 6) for m in (1, 2, 5)]
        cb.set_ticks([v for v in nice if lo - 1e-9 <= v <= hi + 1e-9] or [lo, hi])
        cb.ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{10 ** v:.3g}"))
        ax.set_xlabel("beta, torque-gain scale (-)")
        ax.set_ylabel("alpha, velocity compensation (-)")
        ax.set_title(label if (~stable).any() else f"{label} (torque loop stable in every cell)",
                     fontsize=STYLE["panel_title_size"])
    if any((~p[4]).any() for p in panels):
        fig.legend(handles=[Patch(facecolor="none", edgecolor=STYLE["unstable"], hatch="xxx",
                                  label="torque loop unstable (bandwidth meaningless)")],
                   loc=STYLE["legend_loc"], fontsize=STYLE["legend_size"])
    if title:
        fig.suptitle(_wrap(title, 4.4 * len(panels)), fontsize=_title_size(title, STYLE["title_size"]))
    return fig


def check_title(title: str, field: str = "--title") -> None:
    """Refuse a title matplotlib cannot draw, before any work: text between ``$`` signs is
    parsed as mathtext, and a parse error would otherwise surface only when the figure is saved.

    >>> check_title("HyQ, $N_{av} = 10$")        # passes; "$\\frac{$" raises ParameterError
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure()
    FigureCanvasAgg(fig)
    fig.suptitle(title)
    try:
        fig.canvas.draw()
    except ValueError as exc:
        # mathtext's message is the text, a caret line and the parser's complaint: keep the last
        lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
        why = lines[-1][:200] if lines else type(exc).__name__
        raise ParameterError(f"{field} {title!r}: matplotlib cannot draw it ({why}); allowed: text, math "
                             "between $ signs that matplotlib's mathtext parses, \\$ for a dollar sign") from None


def save_figure(fig, path: str | Path, tx=None, field: str | None = None) -> Path:
    """Save a figure (format from the suffix) and close it.

    Written through the :class:`haa_sym.io.outputs.Transaction` ``tx`` (committed with the other
    outputs of its command), or on its own, atomically, when ``tx`` is None.
    """
    path = Path(path)
    try:
        with transaction(tx) as t, t.open(path, "wb", field) as fh:
            # bbox "tight": a legend below the axes wider than the figure (the robust map's measured
            # points) was cut at the figure's edge
            fig.savefig(fh, format=path.suffix.lstrip(".").lower(), dpi=120, bbox_inches="tight", pad_inches=0.1,
                        metadata={"Software": None} if path.suffix.lower() == ".png" else None)
    finally:
        plt.close(fig)
    return path


# a legend under the axes (below the x label): inside, at the corner, it hid the grid's markers
# there (the whole top row of a schedule whose robust region sits at low P_gain)
_BELOW = dict(loc="upper center", bbox_to_anchor=(0.5, -0.2), borderaxespad=0.0)


def plot_schedule(s, title: str = ""):
    """A :class:`haa_sym.design.schedule.Schedule`: the scheduled beta over the impedance grid (no
    robust gain: grey; beta at the range's top, limited by the range and not the model: red
    triangles) and the torque bandwidth it gains over fixed beta = 1 (impedances where beta = 1
    fails for some leg configuration marked); no robust beta is the same grey in both panels."""
    from matplotlib.colors import LogNorm
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 4.6), layout="constrained")
    logP = bool(np.all(s.P_gain > 0))
    Pe, De = _edges(s.P_gain, logP), _edges(s.D_gain, False)
    PP, DD = np.meshgrid(s.P_gain, s.D_gain, indexing="ij")
    infeasible = ListedColormap(["#ffffff", INFEASIBLE_COLOR])
    for ax in axes:                          # the same colour for "no robust beta" in both panels
        ax.pcolormesh(Pe, De, (~s.feasible).T.astype(float), cmap=infeasible, vmin=0, vmax=1, shading="flat")
    no_beta = Patch(facecolor=INFEASIBLE_COLOR, edgecolor="k", label="no robust beta in the range")
    ax = axes[0]
    b = np.ma.masked_invalid(s.beta)
    pc = ax.pcolormesh(Pe, De, b.T, cmap="viridis", norm=LogNorm(vmin=np.nanmin(s.beta), vmax=np.nanmax(s.beta))
                       if s.feasible.any() else None, shading="flat")
    _plain_ticks(fig.colorbar(pc, ax=ax, label="scheduled beta, Eq. 7 (-)"))
    handles = [no_beta]
    lim = getattr(s, "beta_at_limit", None)
    if lim is not None and lim.any():
        # the range, not the model, sets these values: say so where they are drawn
        handles += ax.plot(PP[lim], DD[lim], "^", mfc="none", color="tab:red", ms=4,
                           label=f"beta at the range's top ({int(lim.sum())} points): limited by the range")
    ax.legend(handles=handles, fontsize=7, **_BELOW)
    ax.set_title("largest robust beta", fontsize=10)
    ax = axes[1]
    bw1 = s.meta.get("torque_bandwidth_beta_1_rad_s")
    gain = np.ma.masked_invalid(s.torque_bandwidth_rad_s / bw1) if bw1 else np.ma.masked_all(s.beta.shape)
    gain = np.ma.masked_where(~s.feasible, gain)
    pc = ax.pcolormesh(Pe, De, gain.T, cmap="magma", shading="flat")
    _plain_ticks(fig.colorbar(pc, ax=ax, label="torque bandwidth / that of beta = 1 (-)"))
    handles = [no_beta]
    bad = s.feasible & ~s.beta_fixed_feasible
    if bad.any():
        # with an uncertainty box the failing configuration may be the box's, not the leg's
        where = "configuration" if s.meta.get("uncertainty") else "leg"
        handles += ax.plot(PP[bad], DD[bad], "x", color="tab:cyan", ms=4, label=f"beta = 1 unsafe for some {where}")
    ax.legend(handles=handles, fontsize=7, **_BELOW)
    ax.set_title("bandwidth gained by the schedule", fontsize=10)
    for ax in axes:
        _gain_axes(ax, logP)
    # the values analysed are always said: the range replaces values edited in the file
    head = "\n".join(t for t in (title, _leg_line(s.meta)) if t)
    if head:
        fig.suptitle(_wrap(head, 10.0), fontsize=_title_size(head, 11))
    return fig


def _leg_line(meta: dict) -> str:
    """The leg range's ends and their values (``meta["leg_values"]``), two lines for a title, and
    the uncertainty box (its keys and ranges) on a third when there is one; "" without."""
    lv = meta.get("leg_values")
    if not lv:
        return ""
    ends = " .. ".join(f"{name} (" + ", ".join(f"{k} {v:.4g}" for k, v in vals.items()) + ")"
                       for name, vals in lv["ends"].items())
    own = ", ".join(f"{k} {v:.4g}" for k, v in lv["own"].items())
    text = f"{ends}\nanalysed instead of the parameters' {own}" + (" (outside the range)" if lv["outside"] else "")
    if lv.get("uncertainty"):
        # analysis.robust.uncertainty_meta: [lo, hi], or {"relative": [lo, hi]} (factors of each
        # leg configuration's value of a key the range sets)
        text += "\nand every value of the uncertainty box " + ", ".join(
            f"{k} x {v['relative'][0]:.5g}..{v['relative'][1]:.5g} of each configuration's value"
            if isinstance(v, dict) else f"{k} {v[0]:.4g}..{v[1]:.4g}" for k, v in lv["uncertainty"].items())
        # the box replaces the file's values too (as the range does): a figure alone must say so
        own_box = lv.get("uncertainty_own") or {}
        if own_box:
            text += " (instead of " + ", ".join(f"{k} {v:.4g}" for k, v in own_box.items()) + ")"
    return text


def plot_robust(r, title: str = "", measured=None):
    """A :class:`haa_sym.analysis.robust.RobustRegion`: the gains meeting the requirements for every leg
    configuration of the range; ``title`` goes above the description of the range; measured
    points over it (``measured``, see :func:`draw_measured`)."""
    fig, ax = plt.subplots(figsize=(4.8, 4.2), layout="constrained")
    logP = bool(np.all(r.P_gain > 0))
    ax.pcolormesh(_edges(r.P_gain, logP), _edges(r.D_gain, False), (~r.feasible).T.astype(float),
                  cmap=ListedColormap(["#ffffff", "#3a3a3a"]), vmin=0, vmax=1, shading="flat")
    _gain_axes(ax, logP)
    leg = r.meta["leg"]
    # the values analysed are always said: the range replaces values edited in the file
    auto = (f"{'+'.join(r.meta['requirements'])} for every leg configuration\n"
            f"{leg[0]}..{leg[1]} ({r.meta['leg_mode']}, {r.n_configurations} configurations; dark: fails)")
    text = "\n".join(t for t in (title, auto, _leg_line(r.meta)) if t)
    ax.set_title(_wrap(text, 4.8, 7), fontsize=7)
    handles = draw_measured(ax, measured, _edges(r.P_gain, logP)[[0, -1]], _edges(r.D_gain, False)[[0, -1]])
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=7)
    return fig


def plot_describing(panels, title: str = ""):
    """Nyquist-type figures of describing-function predictions, one panel per nonlinearity.

    ``panels`` = [dict(label=str, G=complex array (the loop's linear part on its frequency
    grid), minus_inv_N=real array (-1/N(A) on a grid of amplitudes), points=[(G_crossing,
    amplitude, omega, stable)], unit=str)]: G as a curve, -1/N(A) along the negative real axis,
    each predicted limit cycle marked (filled: stable by the Loeb criterion, open: unstable) and
    labelled with its amplitude (in ``unit``) and frequency; several cycles at one crossover (a
    quantiser) share one marker (half filled when stable and unstable mix) and one label with
    their number and amplitude range. The view spans -1 and every
    predicted point (G leaves it where it is larger)."""
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.6 + (0.4 if title else 0)),
                             constrained_layout=True, squeeze=False)
    for ax, p in zip(axes[0], panels):
        G = np.asarray(p["G"])
        pts = p["points"]
        span = 1.6 * max([1.0] + [abs(g) for g, *_ in pts])
        ax.plot(G.real, G.imag, color="k", lw=1.0, label="G(j omega), omega > 0")
        ax.plot(G.real, -G.imag, color="0.6", lw=0.6, ls="--", label="G(-j omega)")
        locus = np.asarray(p["minus_inv_N"], float)
        locus = locus[np.isfinite(locus) & (locus >= -span)]
        if locus.size:
            ax.plot(locus, np.zeros_like(locus), color="tab:red", lw=3, alpha=0.5, solid_capstyle="butt",
                    label="-1/N(A)")
        ax.plot([-1], [0], "+", color="tab:red", ms=10, ls="none", label="-1 (N = 1)")
        # a quantiser meets one crossover at many amplitudes: one marker and one label per
        # crossover (overlaid labels were unreadable); half filled when stable and unstable mix
        by_crossing = {}
        for g, A, w, stable in pts:
            by_crossing.setdefault((g, w), []).append((A, bool(stable)))
        for (g, w), cycles in by_crossing.items():
            n_stable = sum(s for _, s in cycles)
            fill = "full" if n_stable == len(cycles) else "none" if not n_stable else "left"
            ax.plot([g], [0], "o", ms=8, color="tab:blue", fillstyle=fill, mfc="tab:blue" if n_stable else "white",
                    mfcalt="white")
            freq = f"{w:.4g} rad/s ({w / (2 * np.pi):.4g} Hz)"
            if len(cycles) == 1:
                (A, stable), = cycles
                text = f"A = {A:.4g} {p['unit']}\n{freq}\n{'stable' if stable else 'unstable'}"
            else:
                amps = [A for A, _ in cycles]
                text = (f"{len(cycles)} cycles, A = {min(amps):.4g} .. {max(amps):.4g} {p['unit']}\n{freq}\n"
                        f"{n_stable} stable, {len(cycles) - n_stable} unstable")
            ax.annotate(text, (g, 0), textcoords="offset points", xytext=(6, 10), fontsize=8)
        ax.set_xlim(-span, 0.5 * span)
        ax.set_ylim(-0.8 * span, 0.8 * span)
        ax.axhline(0, color="0.8", lw=0.6)
        ax.axvline(0, color="0.8", lw=0.6)
        ax.set_xlabel("Re")
        ax.set_ylabel("Im")
        ax.set_title(_wrap(p["label"], 5.2, 9), fontsize=9)
        ax.grid(True, alpha=0.3)
        # what the marker fill means, whether or not this panel has such a cycle
        marks = [plt.Line2D([], [], ls="none", marker="o", ms=7, color="tab:blue", fillstyle=f, mfc=c,
                            label=lab) for f, c, lab in (("full", "tab:blue", "limit cycle, stable (Loeb)"),
                                                        ("none", "white", "limit cycle, unstable (Loeb)"))]
        handles, _ = ax.get_legend_handles_labels()
        ax.legend(handles=handles + marks, fontsize=7, loc="lower left")
    if title:
        fig.suptitle(_wrap(title, 5.2 * len(panels)), fontsize=_title_size(title, 10))
    return fig


def plot_tune(lead_s, integral, grid_objective, before, after, steps, title: str = "",
              ylabel: str = "torque (Nm)", notes: str = "", band: float | None = None):
    """``haa-sym tune``: left, the coarse search grid, the objective (rad/s) where every target is
    met (blank: some target missed) over the PI's lead time tau = P_t0 / I_t0 (s; the first row,
    tau = 0, the pure integrator, drawn at the bottom) and I_t0 (V/(Nm s)), with the file's and
    the tuned PI marked; right, unit torque steps ``steps`` = [(t, T, label, linestyle)], the
    settling band +-``band`` around 1 if given, and ``notes`` (the torque-loop figures, one
    line each) above the step panel."""
    lead_s, integral, obj = (np.asarray(a, float) for a in (lead_s, integral, grid_objective))
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.4 + (0.6 if title else 0)), constrained_layout=True)
    # tau = 0 cannot sit on a log axis: its row is drawn one grid step below the smallest tau
    pos = lead_s[1:]
    step = pos[1] / pos[0] if pos.size > 1 else 10.0
    y = np.concatenate([[pos[0] / step], pos])
    img = ax.pcolormesh(_edges(integral, True), _edges(y, True), np.ma.masked_invalid(obj), cmap="viridis",
                        shading="flat")
    ax.set_xscale("log")
    ax.set_yscale("log")
    cbar = fig.colorbar(img, ax=ax)
    cbar.set_label("objective: torque bandwidth (rad/s)")

    def mark(P, I, label, style):
        tau = P / I if I > 0 else 0.0
        ax.plot([I], [tau if tau > 0 else y[0]], style, ms=9, mfc="none", mew=2, label=label)
    mark(before[0], before[1], f"file: P_t0 = {before[0]:.4g}, I_t0 = {before[1]:.4g}", "rs")
    mark(after[0], after[1], f"tuned: P_t0 = {after[0]:.4g}, I_t0 = {after[1]:.4g}", "m*")
    ax.set_xlabel("I_t0 (V/(Nm s))")
    ax.set_ylabel("tau = P_t0 / I_t0 (s); bottom row: tau = 0")
    ax.set_title("feasible PIs (blank: a target missed)", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    for t, T, label, ls in steps:
        ax2.plot(t, T, ls, label=label)
    ax2.axhline(1.0, color="0.6", lw=0.8)
    ax2.axhline(0.9, color="0.6", lw=0.8, ls=":")
    if band:
        ax2.axhspan(1 - band, 1 + band, color="0.85", alpha=0.5, lw=0, label=f"+-{100 * band:g} % (settling)")
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel(ylabel)
    # one wrapped block per note: a line wider than the panel ran off the figure
    notes = "\n".join(textwrap.fill(n, 90, subsequent_indent="  ") for n in notes.splitlines())
    ax2.set_title("unit torque step, impedance loop open" + (f"\n{notes}" if notes else ""),
                  fontsize=10 if not notes else 7, loc="center" if not notes else "left")
    ax2.legend(fontsize=8)
    ax2.grid(True, alpha=0.3)
    if title:
        fig.suptitle(_wrap(title, 11), fontsize=_title_size(title, 11))
    return fig


def plot_simulation(time, columns: dict, saturated=None, title: str = "", cycle: str = "",
                    command: str = "voltage (V)"):
    """A simulated run (``haa-sym simulate``): angle and velocity, torque and its reference,
    the held command (``columns["voltage"]``, labelled ``command``: a current command's is a
    current; saturated samples marked) and current over ``time`` (s). ``columns`` maps the CSV
    names to arrays; ``cycle`` is a note on a detected limit cycle (shown in the torque panel)."""
    t = np.asarray(time)
    cycle = _wrap(cycle, 5.4, 7)            # the panel's width, not the figure's
    fig, axes = plt.subplots(4, 1, figsize=(6.4, 8.0 + (0.6 if title else 0) + 0.12 * cycle.count("\n")), sharex=True,
                             constrained_layout=True)
    axes[0].plot(t, columns["theta"], color="k", label="theta (encoder)")
    axes[0].set_ylabel("theta (rad)")
    ax2 = axes[0].twinx()
    ax2.plot(t, columns["velocity"], color="tab:blue", lw=0.8)
    ax2.set_ylabel("port velocity (rad/s)", color="tab:blue")
    axes[1].plot(t, columns["torque"], color="k", label="torque (read by the loop)")
    axes[1].plot(t, columns["torque_ref"], color="tab:orange", lw=0.8, label="torque reference")
    axes[1].set_ylabel("torque (Nm)")
    axes[1].legend(fontsize=8)
    if cycle:
        # above the panel, not in its legend: a legend this long covered the trace it describes
        axes[1].set_title(cycle, fontsize=7, loc="left")
    axes[2].plot(t, columns["voltage"], color="k")
    if saturated is not None and np.any(saturated):
        sat = np.asarray(saturated, bool)
        axes[2].plot(t[sat], np.asarray(columns["voltage"])[sat], ".", ms=2, color="tab:red",
                     label="saturated")
        axes[2].legend(fontsize=8)
    axes[2].set_ylabel(command)
    axes[3].plot(t, columns["current"], color="k")
    axes[3].set_ylabel("current (A)")
    axes[3].set_xlabel("t (s)")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    if title:
        fig.suptitle(_wrap(title, 6.4), fontsize=_title_size(title, 11))
    return fig


_UNITS = OUTPUT_UNITS


# The zoomed time panel of plot_identify: the log's last stretch with this many crossings of the
# measured output's mean (about a dozen oscillations: each one readable at a panel's width; the
# whole log of a broadband excitation is a solid band, docs/identify.md, "Outputs").
ZOOM_CROSSINGS = 24


def _zoom_start(t: np.ndarray, y: np.ndarray, crossings: int = ZOOM_CROSSINGS, min_samples: int = 50) -> int:
    """Index where the zoom window of a trace begins: the last ``crossings`` crossings of its mean
    (at least ``min_samples`` samples, at most the whole trace)."""
    s = np.signbit(y - np.mean(y))
    idx = np.flatnonzero(s[1:] != s[:-1])
    start = int(idx[-crossings]) if idx.size >= crossings else 0
    return max(0, min(start, t.size - min_samples))


# plot_identify draws at most this many validation data sets (a row each)
MAX_VALIDATION_ROWS = 3


def plot_identify(result, title: str = "", max_points: int = 4000, validation=None):
    """``haa-sym identify --plot``: per output, the first log's measured trace against the
    model's prediction before (initial values) and after the fit, over the whole log (every
    ``len // max_points``-th sample) and zoomed on its last :data:`ZOOM_CROSSINGS` crossings of
    the mean (every sample; the zoom is shaded on the whole log); below, the Bode magnitude and
    phase of the Welch H1 estimate (first input to the output) with the model's before and
    after, and the coherence. ``result`` is a :class:`haa_sym.fit.identify.FitResult` computed
    with ``figure_data=True``. ``validation``: ``(traces, quality)`` of
    :func:`haa_sym.fit.identify.validate`; the data sets that were not fitted (a held-out part, a
    --validate log; at most :data:`MAX_VALIDATION_ROWS`) get a row each below the zoom, measured
    against the fitted model over the scored samples, titled with NRMSE and VAF, and the fitted
    log's own NRMSE and VAF are in its title."""
    tr = result.traces[0]
    bode = result.bode[0] if result.bode else None
    outs = tuple(tr.get("outputs", result.outputs))      # the first log's own outputs
    fitted_names = {t["name"] for t in result.traces}
    val_traces, quality = validation if validation is not None else ([], {})
    held = [v for v in val_traces if v["name"] not in fitted_names][:MAX_VALIDATION_ROWS]
    nv = len(held)
    rows = 2 + nv + (3 if bode is not None else 0)
    fig, axes = plt.subplots(rows, len(outs), figsize=(6 * len(outs), 2.5 * rows), squeeze=False,
                             layout="constrained")
    t = tr["t"]
    whole = slice(None, None, max(1, len(t) // max_points))
    # wide and light underneath: where the fit is good the model lies on the measurement
    styles = (("measured", dict(color=STYLE["data"], lw=3.0, label="measured")),
              ("initial", dict(color=STYLE["before"], lw=0.8, ls="--", label="model, initial")),
              ("fitted", dict(color=STYLE["after"], lw=0.8, label="model, fitted")))
    for i, o in enumerate(outs):
        ax, zoom = axes[0, i], axes[1, i]
        k0 = _zoom_start(t, tr["measured"][:, i])
        near = slice(k0, None, max(1, (len(t) - k0) // max_points))
        for key, style in styles:
            ax.plot(t[whole], tr[key][whole, i], **style)
            zoom.plot(t[near], tr[key][near, i], **style)
        ax.axvspan(t[k0], t[-1], color=STYLE["reference"], alpha=0.25, lw=0, label="zoomed below")
        ax.set_xlim(t[0], t[-1])
        zoom.set_xlim(t[k0], t[-1])
        ax.set_xlabel("t (s), the whole log")
        zoom.set_xlabel(f"t (s), the log's last {t[-1] - t[k0]:.3g} s")
        for a in (ax, zoom):
            a.set_ylabel(f"{o} ({_UNITS[o]})")
        own = quality.get(tr["name"], {}).get(o)
        ax.set_title(f"{tr['name']}: {o}, rms error {result.rms_initial[o]:.3g} -> {result.rms_fitted[o]:.3g}"
                     + (f"; fit data NRMSE {own['nrmse']:.3g}, VAF {own['vaf_percent']:.4g} %" if own else ""),
                     fontsize=STYLE["panel_title_size"])
        for j, v in enumerate(held):
            # zoomed as the fit data's second row: the whole of a broadband log is a solid band
            va, tv = axes[2 + j, i], v["t"]
            vo = tuple(v.get("outputs", outs))
            if o not in vo:                      # a validation log of other outputs (per-log --output)
                va.set_axis_off()
                continue
            iv = vo.index(o)
            kv = _zoom_start(tv, v["measured"][:, iv])
            step = slice(kv, None, max(1, (len(tv) - kv) // max_points))
            va.plot(tv[step], v["measured"][step, iv], **styles[0][1])
            va.plot(tv[step], v["fitted"][step, iv], **styles[2][1])
            va.set_xlim(tv[kv], tv[-1])
            va.set_xlabel(f"t (s), the last {tv[-1] - tv[kv]:.3g} s of validation data (not fitted; scores over "
                          f"{tv[0]:.3g} .. {tv[-1]:.3g} s)")
            va.set_ylabel(f"{o} ({_UNITS[o]})")
            q = quality[v["name"]][o]
            va.set_title(f"validation {v['name']}: {o}, NRMSE {q['nrmse']:.3g}, VAF {q['vaf_percent']:.4g} %",
                         fontsize=STYLE["panel_title_size"])
        if bode is None:
            continue
        w = bode["omega"]
        mag, ph, coh = axes[2 + nv, i], axes[3 + nv, i], axes[4 + nv, i]
        # H1 only where the coherence says the measurement carries the input (>= 0.5)
        H1 = np.where(bode["coherence"][i] >= 0.5, bode["H1"][i], np.nan)
        # H1's phase as its angle from the fitted model's, added to that model's unwrapped phase:
        # np.unwrap over the NaN gaps of the coherence mask turns every later point into NaN (the
        # measured phase vanished), and unwrapping noisy H1 alone can land 360 deg off the model
        fitted_ph = np.unwrap(np.angle(bode["fitted"][i]))
        for G, style, phase in (
                (H1, dict(color=STYLE["data"], lw=3.0, label="H1 (Welch), coherence >= 0.5"),
                 fitted_ph + np.angle(H1 / bode["fitted"][i])),
                (bode["initial"][i], dict(color=STYLE["before"], lw=0.8, ls="--", label="model, initial"),
                 np.unwrap(np.angle(bode["initial"][i]))),
                (bode["fitted"][i], dict(color=STYLE["after"], lw=0.8, label="model, fitted"), fitted_ph)):
            mag.loglog(w, np.abs(G), **style)
            ph.semilogx(w, np.degrees(phase), **style)
        mag.set_ylabel(f"|{o} / {result.inputs[0]}|")
        ph.set_ylabel("phase (deg)")
        coh.semilogx(w, bode["coherence"][i], color="k", lw=0.8)
        coh.set_ylim(0, 1.05)
        coh.set_ylabel("coherence")
        coh.set_xlabel("omega (rad/s)")
    # one legend for every panel, below them (the traces' legends covered the whole-log data)
    data_label = "measured" + ("; Bode: H1 (Welch) where the coherence >= 0.5" if bode is not None else "")
    handles = [plt.Line2D([], [], **{**styles[0][1], "label": data_label}),
               plt.Line2D([], [], **styles[1][1]), plt.Line2D([], [], **styles[2][1]),
               Patch(color=STYLE["reference"], alpha=0.25, lw=0, label="the zoomed window")]
    fig.legend(handles=handles, loc=STYLE["legend_loc"], ncol=4, fontsize=STYLE["legend_size"])
    if title:
        fig.suptitle(_wrap(title, 6 * len(outs)), fontsize=_title_size(title, STYLE["title_size"]))
    return fig
