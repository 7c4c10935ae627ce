"""The paper's figures (Sobhani Tehrani et al., EMBC 2014, Figs. 3-5) and a truth check.

Every function draws into the axes it is given (``ax``) or into a new figure when ``ax``
is None, and returns the :class:`matplotlib.figure.Figure` it drew into (its axes are
``fig.axes``). Nothing here calls ``plt.show()`` or selects a backend: scripts and tests
choose one (``matplotlib.use("Agg")`` for files).

Figures of the identified model show what the data support: confidence bands where the
model carries intervals (:mod:`lpvpc.models.uncertainty`), a strip with the density of the
scheduling variable and delayed velocity seen at identification under Figs. 4 and 5A
(``model.fit["data_density"]``), and curves only where there were data.

Units: time s, position and scheduling rad, velocity rad/s, torque N m, stiffness and
intrinsic gain N m/rad, frequency Hz.

- :func:`plot_torque_fit` (Fig. 3): measured vs predicted perturbation torque, with the
  intrinsic and reflex parts;
- :func:`plot_intrinsic_gain` (Fig. 4): intrinsic gain over frequency and position, with
  the elastic stiffness K(rho);
- :func:`plot_reflex_nonlinearity` (Fig. 5A): reflex static nonlinearity over velocity
  at several positions;
- :func:`plot_reflex_irf` (Fig. 5B): impulse response of the reflex linear dynamics;
- :func:`plot_stiffness_vs_truth`: identified K(rho) against a known K(theta).
"""

from __future__ import annotations

import numpy as np

# Central part of the identified scheduling range over which K is judged (and shaded).
CENTRAL_FRACTION = 0.8


def _new_axes(ax, **subplot_kw):
    if ax is not None:
        return ax
    from matplotlib.figure import Figure

    # A Figure outside pyplot's global state: it renders with Agg (fig.savefig) and is
    # displayed like any figure in a notebook.
    return Figure(figsize=(7, 5)).add_subplot(**subplot_kw)


def _density(model):
    """The stored joint histogram (scheduling x delayed velocity) or None (older models)."""
    d = model.fit.get("data_density") if isinstance(model.fit, dict) else None
    if not d:
        return None
    return (np.asarray(d["scheduling_edges"], dtype=float), np.asarray(d["velocity_edges"], dtype=float),
            np.asarray(d["counts"], dtype=float))


def _density_strip(ax, edges, counts, label, log=False):
    """A strip under ``ax`` (same x axis) with the histogram of the data seen at
    identification (``log``: log10(1 + count), for peaked distributions); the x label
    moves to the strip. Returns the strip axes."""
    strip = ax.inset_axes([0.0, -0.26, 1.0, 0.14], sharex=ax)
    h = np.log10(1.0 + counts) if log else counts
    strip.bar(edges[:-1], h, width=np.diff(edges), align="edge", color="0.55", lw=0)
    strip.set_yticks([])
    strip.set_ylabel("samples\n(log)" if log else "samples", rotation=0, ha="right", va="center", fontsize="small")
    strip.set_xlabel(label)
    strip.set_ylim(0, max(float(np.max(h)), 1.0) * 1.05)
    ax.set_xlabel("")
    ax.tick_params(axis="x", labelbottom=False)
    return strip


MIN_SAMPLES = 5  # a curve is drawn through a histogram bin with at least this many samples


def _supported(model, rho, velocity):
    """Mask (len(rho), len(velocity)): True where identification saw data (>= MIN_SAMPLES
    in the joint histogram bin, or a neighbour bin in position), everywhere for old models."""
    dens = _density(model)
    if dens is None:
        return np.ones((len(rho), len(velocity)), dtype=bool)
    e_r, e_v, counts = dens
    # a position between bins is supported by the bins on either side (positions are a
    # continuum; the histogram is coarse)
    padded = np.maximum(counts, np.maximum(np.vstack([counts[1:], counts[-1:]]), np.vstack([counts[:1], counts[:-1]])))
    i = np.clip(np.searchsorted(e_r, rho, side="right") - 1, 0, len(e_r) - 2)
    j = np.searchsorted(e_v, velocity, side="right") - 1
    inside = (j >= 0) & (j <= len(e_v) - 2) & (velocity >= e_v[0]) & (velocity <= e_v[-1])
    j = np.clip(j, 0, len(e_v) - 2)
    ok = (padded[i][:, j] >= MIN_SAMPLES) & inside[None, :]
    for row in ok:  # from the slowest to the fastest supported velocity, without holes
        idx = np.flatnonzero(row)
        if idx.size:
            row[idx[0]:idx[-1] + 1] = True
    return ok


def _legend_outside(ax, **kw):
    """Legend to the right of the axes, never over the curves."""
    return ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize="small", **kw)


def _positions(model, n):
    lo, hi = model.scheduling_range
    return np.array([lo]) if model.one_position else np.linspace(lo, hi, n)


def _position_colours(n):
    import matplotlib

    cmap = matplotlib.colormaps["viridis"]
    return [cmap(x) for x in np.linspace(0.0, 0.9, n)]


# --------------------------------------------------------------------------- Fig. 3


def plot_torque_fit(time, measured, prediction, ax=None, *, fig=None, window=None):
    """Measured vs predicted perturbation torque (N m) over time (s) (Fig. 3).

    ``prediction`` is a :class:`lpvpc.models.model.Prediction` (total, intrinsic, reflex) or an
    array of predicted total torque. Layout:

    - ``ax`` None: three stacked axes (total, intrinsic, reflex) in ``fig`` (a new figure
      if ``fig`` is None);
    - ``ax`` a sequence of three axes: the same, drawn into them;
    - ``ax`` one axes: everything overlaid in it.

    Parameters
    ----------
    time : array_like
        Time stamps (s).
    measured : array_like
        The measured perturbation torque (N m).
    prediction : lpvpc.models.model.Prediction or array_like
        The prediction (total, intrinsic, reflex), or the predicted total torque (N m).
    ax : matplotlib.axes.Axes or list of matplotlib.axes.Axes, optional
        Where to draw (layout above); None: three new stacked axes.
    fig : matplotlib.figure.Figure, optional
        The figure for new axes; None: a new figure.
    window : tuple of float, optional
        ``(t0, t1)`` in s: restricts the plot to that interval (the whole record is
        unreadable at 100 Hz over 2 minutes).

    Returns
    -------
    matplotlib.figure.Figure
        The figure drawn into.

    Raises
    ------
    ValueError
        ``ax`` a sequence of other than three axes.
    """
    time = np.asarray(time, dtype=float)
    measured = np.asarray(measured, dtype=float)
    total = np.asarray(getattr(prediction, "total", prediction), dtype=float)
    intrinsic = getattr(prediction, "intrinsic", None)
    reflex = getattr(prediction, "reflex", None)
    sel = np.ones(len(time), dtype=bool)
    if window is not None:
        sel = (time >= window[0]) & (time <= window[1])
    t = time[sel]

    single = ax is not None and not isinstance(ax, (list, tuple, np.ndarray))
    if single:
        ax.plot(t, measured[sel], color="0.6", lw=1.0, label="measured")
        ax.plot(t, total[sel], color="C0", lw=1.0, label="predicted")
        if intrinsic is not None:
            ax.plot(t, np.asarray(intrinsic)[sel], color="C1", lw=0.8, label="intrinsic")
        if reflex is not None:
            ax.plot(t, np.asarray(reflex)[sel], color="C3", lw=0.8, label="reflex")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("torque (N m)")
        ax.legend(loc="upper right", fontsize="small", ncol=2)
        return ax.figure

    if ax is None:
        from matplotlib.figure import Figure

        fig = fig if fig is not None else Figure(figsize=(9, 6.5))
        axes = fig.subplots(3, 1, sharex=True)
    else:
        axes = np.asarray(ax)
        if axes.size != 3:
            raise ValueError(f"plot_torque_fit needs one axes or three, got {axes.size}")
    axes = np.asarray(axes).ravel()
    a0, a1, a2 = axes
    a0.plot(t, measured[sel], color="0.6", lw=1.0, label="measured")
    a0.plot(t, total[sel], color="C0", lw=1.0, label="predicted")
    a0.set_ylabel("total (N m)")
    a0.legend(loc="upper right", fontsize="small", ncol=2)
    for a, part, colour, name in ((a1, intrinsic, "C1", "intrinsic"), (a2, reflex, "C3", "reflex")):
        if part is not None:
            a.plot(t, np.asarray(part, dtype=float)[sel], color=colour, lw=1.0)
        else:
            a.text(0.5, 0.5, f"no {name} part given", transform=a.transAxes, ha="center", va="center")
        a.set_ylabel(f"{name} (N m)")
    a2.set_xlabel("time (s)")
    a0.set_title("perturbation torque: measured vs predicted")
    return a0.figure


# --------------------------------------------------------------------------- Fig. 4


def plot_intrinsic_gain(model, ax=None, *, kind="image", n_freq=101, n_rho=61, positions=7, level=0.95):
    """Intrinsic gain |H(f, rho)| (N m/rad) over frequency 0..fs/2 (Hz) and position (rad)
    (Fig. 4; the elastic stiffness K(rho) is its value at 0 Hz). Returns the figure.

    ``kind``:

    - "image" (default): colour map of the gain over position (x) and frequency (y), and
      under it the density of the scheduling variable seen at identification (K(rho) with
      its band has its own figure, :func:`plot_stiffness_and_reflex`: one y-axis per
      quantity);
    - "curves": gain vs frequency for ``positions`` positions (the curves start at K(rho));
    - "surface": the paper's 3-D surface; ``ax`` must be a 3-D axes or None.

    A stationary trial's model (one operating position, :attr:`LPVPCModel.one_position <lpvpc.models.model.LPVPCModel.one_position>`) is
    drawn as "curves": its one curve; there is no position axis.
    """
    freqs = np.linspace(0.0, model.fs / 2, n_freq)
    if model.one_position and kind in ("image", "surface"):
        kind = "curves"
    if kind == "curves":
        ax = _new_axes(ax)
        rho = _positions(model, positions)
        gain = np.abs(model.intrinsic_frequency_response(freqs, rho))
        for r, g, c in zip(rho, gain, _position_colours(len(rho))):
            ax.plot(freqs, g, color=c, label=f"{r:+.2f} rad (K = {g[0]:.0f})")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("intrinsic gain (N m/rad)")
        ax.set_xlim(freqs[0], freqs[-1])
        _legend_outside(ax, title="position")
        ax.set_title("intrinsic stiffness gain")
        return ax.figure

    rho = _positions(model, n_rho)
    gain = np.abs(model.intrinsic_frequency_response(freqs, rho))  # (n_rho, n_freq)
    if kind == "surface":
        ax = _new_axes(ax, projection="3d")
        R, F = np.meshgrid(rho, freqs, indexing="ij")
        ax.plot_surface(R, F, gain, cmap="viridis", linewidth=0, antialiased=True)
        ax.set_xlabel("position (rad)")
        ax.set_ylabel("frequency (Hz)")
        ax.set_zlabel("gain (N m/rad)")
        ax.set_title("intrinsic stiffness gain")
        return ax.figure
    if kind != "image":
        raise ValueError(f"kind must be 'image', 'curves' or 'surface', got {kind!r}")

    from matplotlib.colors import LogNorm

    ax = _new_axes(ax)
    # Log colour scale: inertia dominates at high frequency (I w^2); the position dependence
    # of the low-frequency gain and of the resonance valley would vanish on a linear scale.
    positive = gain[gain > 0]
    norm = LogNorm(vmin=positive.min(), vmax=positive.max()) if positive.size else None
    mesh = ax.pcolormesh(rho, freqs, gain.T, shading="auto", cmap="viridis", norm=norm)
    ax.figure.colorbar(mesh, ax=ax, location="top", label="|H| (N m/rad, log colour scale)", fraction=0.05, pad=0.02)
    ax.set_xlabel("position rho (rad, + = dorsiflexion)")
    ax.set_ylabel("frequency (Hz)")
    dens = _density(model)
    if dens is not None:
        _density_strip(ax, dens[0], dens[2].sum(axis=1), "position rho (rad, + = dorsiflexion)")
    return ax.figure


def plot_stiffness_and_reflex(model, axes=None, *, level=0.95, marks=None):
    """The answer of a report in one figure: elastic stiffness K(rho) (N m/rad, left) and
    reflex gain (N m s/rad, right) over the identified range (rad), each on its own y-axis
    with its ``level`` confidence band when the model carries intervals. Positions where the
    data do not determine the reflex gain are left out of its curve and marked on the axis.
    ``marks``: positions (rad) to dot on both curves (the positions of the report's table).
    ``axes``: two axes (default: a new figure). A stationary trial's model (one position)
    is drawn as points with error bars. Returns the figure.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> from lpvpc.identification.identify import identify
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut), structure="fixed")
    >>> fig = plot_stiffness_and_reflex(model)
    >>> [a.get_ylabel() for a in fig.axes]
    ['elastic stiffness K (N m/rad)', 'reflex gain (N m s/rad)']
    """
    from .models.uncertainty import NOT_DETERMINED

    if axes is None:
        from matplotlib.figure import Figure

        axes = Figure(figsize=(9, 3.0)).subplots(1, 2)
    ax_k, ax_g = axes
    lo, hi = model.scheduling_range
    one = bool(model.one_position)
    rho = np.array([lo]) if one else np.linspace(lo, hi, 121)
    K = model.elastic_stiffness(rho)
    G = model.reflex_gain_threshold(rho)[0]
    has = model.has_intervals
    ci_k = model.elastic_stiffness_interval(rho, level) if has else None
    ci_g = model.reflex_gain_interval(rho, level) if has else None
    g_ok = np.asarray(ci_g.determined if has else np.ones(len(rho), bool), dtype=bool)
    band = f"{level:.0%} confidence band"
    if one:
        yerr_k = None if not has else [[K[0] - ci_k[0][0]], [ci_k[1][0] - K[0]]]
        ax_k.errorbar(rho, K, yerr=yerr_k, fmt="o", color="C0", capsize=4)
        if g_ok[0]:
            yerr_g = None if not has else [[G[0] - ci_g[0][0]], [ci_g[1][0] - G[0]]]
            ax_g.errorbar(rho, G, yerr=yerr_g, fmt="o", color="C1", capsize=4)
        for ax in axes:
            ax.set_xlim(lo - 0.05, lo + 0.05)
    else:
        if has:
            ax_k.fill_between(rho, ci_k[0], ci_k[1], color="C0", alpha=0.25, lw=0, label=band)
            ax_g.fill_between(rho, np.where(g_ok, ci_g[0], np.nan), np.where(g_ok, ci_g[1], np.nan), color="C1",
                              alpha=0.25, lw=0, label=band)
        ax_k.plot(rho, K, color="C0", lw=2, label="K (stiffness at 0 Hz)")
        ax_g.plot(rho, np.where(g_ok, G, np.nan), color="C1", lw=2, label="reflex gain")
        if not g_ok.all():
            ax_g.plot(np.where(~g_ok, rho, np.nan), np.zeros(len(rho)), color="0.5", lw=4, alpha=0.5,
                      label=NOT_DETERMINED)
        if marks is not None and len(marks):
            m = np.asarray(marks, dtype=float)
            ax_k.plot(m, model.elastic_stiffness(m), "o", color="C0", ms=4)
            ok = model.reflex_gain_interval(m, level).determined if has else np.ones(len(m), bool)
            gm = model.reflex_gain_threshold(m)[0]
            ax_g.plot(m[ok], gm[ok], "o", color="C1", ms=4)
        for ax in axes:
            ax.set_xlim(lo, hi)
            ax.legend(fontsize="small", loc="upper left", frameon=False)
    ax_k.set_ylabel("elastic stiffness K (N m/rad)")
    ax_g.set_ylabel("reflex gain (N m s/rad)")
    ax_k.set_ylim(bottom=0)
    ax_g.axhline(0.0, color="0.7", lw=0.6)
    for ax in axes:
        ax.set_xlabel("position (rad, + = dorsiflexion)")
        ax.grid(alpha=0.3)
    ax_k.figure.tight_layout()
    return ax_k.figure


# --------------------------------------------------------------------------- Fig. 5


def plot_reflex_nonlinearity(model, ax=None, *, positions=5, velocity=None, truth=None, level=0.95):
    """Reflex static nonlinearity f(v, rho) (N m, steady reflex torque for a constant
    delayed velocity v in rad/s) for ``positions`` positions across the identified range
    (Fig. 5A), with ``level`` confidence bands when the model carries intervals and, under
    it, the density of the delayed velocity seen at identification. At a position where the
    data do not determine the reflex (its gain interval reaches zero,
    :meth:`lpvpc.models.model.LPVPCModel.reflex_determined`) no curve is drawn and the legend says
    "not determined by these data"; where only the threshold is not determined the curve is
    drawn and the legend (or a note, when that holds at every position) says so. Each curve is drawn
    only where identification saw data at that position and velocity (no polynomial lobes
    beyond the data). ``velocity`` defaults to the identified velocity range. Returns the
    figure.

    ``truth``: optional object with ``reflex_gain(theta)`` and ``reflex_threshold(theta)``
    (e.g. :class:`~lpvpc.simulation.subject.SubjectParams`); its half-wave rectifiers are drawn dashed.
    """
    ax = _new_axes(ax)
    rho = _positions(model, positions) if np.ndim(positions) == 0 else np.asarray(positions, dtype=float)
    if velocity is None:
        basis = model.nonlinearity()[0]
        velocity = np.linspace(basis.lo, basis.hi, 241)
        ok = _supported(model, rho, velocity)
        cols = np.flatnonzero(ok.any(axis=0))
        if cols.size:  # the axis spans the velocities seen, not the sparse extremes
            velocity = np.linspace(velocity[cols[0]], velocity[cols[-1]], 241)
    velocity = np.asarray(velocity, dtype=float)
    curves = model.reflex_nonlinearity(velocity, rho)
    ok = _supported(model, rho, velocity)
    band = None
    from .models.uncertainty import NOT_DETERMINED

    g_ok, th_ok = model.reflex_determined(rho, level)  # all True without intervals
    if model.has_intervals:
        from .models.reflex_uncertainty import nonlinearity_band

        band = nonlinearity_band(model, velocity, rho, level)
    for k, (r, f, c) in enumerate(zip(rho, curves, _position_colours(len(rho)))):
        if not g_ok[k]:  # the data cannot tell this position's reflex from none: no curve to draw
            ax.plot([], [], color=c, ls=":", label=f"{r:+.2f} rad: {NOT_DETERMINED}")
            continue
        f = np.where(ok[k], f, np.nan)
        if band is not None:
            ax.fill_between(velocity, band[0][k], band[1][k], where=ok[k], color=c, alpha=0.18, lw=0)
        partly = "" if th_ok[k] or not th_ok.any() else f" (threshold {NOT_DETERMINED})"
        ax.plot(velocity, f, color=c, label=f"{r:+.2f} rad{partly}")
        if truth is not None:
            g, th = float(truth.reflex_gain(r)), float(truth.reflex_threshold(r))
            ax.plot(velocity, np.where(ok[k], g * np.maximum(velocity - th, 0.0), np.nan), color=c, ls="--", lw=0.9)
    ax.axhline(0.0, color="0.7", lw=0.6)
    ax.set_xlabel("delayed stretch velocity (rad/s)")
    ax.set_ylabel("steady reflex torque (N m)")
    extra = [] if band is None else [f"bands: {level:.0%} confidence"]
    if truth is not None:
        extra.append("dashed: truth")
    ax.set_title("reflex nonlinearity" + (f" ({'; '.join(extra)})" if extra else ""), fontsize="medium")
    _legend_outside(ax, title="position")
    # notes at the top left, where a stretch reflex's curve (flat, then rising with stretch velocity)
    # leaves room; at the bottom they ran over the curve's flat part and the zero line
    note = dict(transform=ax.transAxes, ha="left", va="top", fontsize="x-small", color="0.35",
                bbox=dict(facecolor="white", alpha=0.8, edgecolor="none", pad=1.0))
    if model.reflex_threshold_biased:
        # short lines: one long line overran the axes' edge (onto the tick labels or the legend)
        ax.text(0.02, 0.98, f"seen on {model.nonlinearity_fs:g} Hz velocity:\nthe threshold is biased (a soft rectifier)"
                + (f"\nthreshold {NOT_DETERMINED}" if not th_ok.any() else ""), **note)
    elif not th_ok.any() and g_ok.any():
        ax.text(0.02, 0.98, f"threshold {NOT_DETERMINED}", **note)
    dens = _density(model)
    if dens is not None:
        _density_strip(ax, dens[1], dens[2].sum(axis=0), "delayed stretch velocity (rad/s)", log=True)
    ax.set_xlim(velocity[0], velocity[-1])
    return ax.figure


def plot_reflex_irf(model, ax=None, *, duration=0.6, truth=None):
    """Impulse response of the reflex linear dynamics (Fig. 5B), normalised to unit static
    gain and scaled to 1/s (a continuous-time IRF with unit area; the static gain sits in
    the nonlinearity of Fig. 5A). Time in s from the delayed velocity.

    ``truth``: optional object with ``reflex_wn`` (rad/s) and ``reflex_zeta``: the
    unit-gain 2nd-order low-pass it describes is drawn dashed.
    """
    ax = _new_axes(ax)
    t, h = model.reflex_impulse_response(int(round(duration * model.fs)))
    dc = model.reflex_static_gain()
    scale = model.fs / dc if dc != 0 else model.fs
    ax.plot(t, h * scale, "o-", ms=3, lw=1.2, label=f"identified (order {model.state_order})")
    if truth is not None:
        wn, zeta = float(truth.reflex_wn), float(truth.reflex_zeta)
        tt = np.linspace(0.0, t[-1], 400)
        if zeta < 1:
            wd = wn * np.sqrt(1 - zeta**2)
            ht = wn**2 / wd * np.exp(-zeta * wn * tt) * np.sin(wd * tt)
        else:  # critically/over-damped: use the repeated-pole form as the limit
            ht = wn**2 * tt * np.exp(-wn * tt)
        ax.plot(tt, ht, "--", color="k", lw=1.0, label=f"truth (wn {wn:g} rad/s, zeta {zeta:g})")
    ax.axhline(0.0, color="0.7", lw=0.6)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("impulse response (1/s, unit static gain)")
    ax.set_xlim(0.0, t[-1])
    ax.set_title("reflex dynamics")
    ax.legend(fontsize="small", loc="upper right")
    return ax.figure


# --------------------------------------------------------------------------- truth check


def plot_stiffness_vs_truth(model, truth_theta, truth_K, ax=None, *, level=0.95):
    """Identified elastic stiffness K(rho) over the identified range against a known
    K(theta) (N m/rad vs rad), with its ``level`` confidence band when the model carries
    intervals; the central 80 % of the identified range, where K is judged, is shaded and
    the worst error there is given in the legend. Returns the figure."""
    ax = _new_axes(ax)
    truth_theta = np.asarray(truth_theta, dtype=float)
    truth_K = np.asarray(truth_K, dtype=float)
    lo, hi = model.scheduling_range
    rho = np.linspace(lo, hi, 200)
    K = model.elastic_stiffness(rho)
    margin = (1 - CENTRAL_FRACTION) / 2 * (hi - lo)
    c_lo, c_hi = lo + margin, hi - margin
    order = np.argsort(truth_theta)
    ax.plot(truth_theta[order], truth_K[order], "k--", lw=1.2, label="truth")
    central = (rho >= c_lo) & (rho <= c_hi)
    truth_at = np.interp(rho[central], truth_theta[order], truth_K[order])
    worst = float(np.max(np.abs(K[central] / truth_at - 1))) * 100 if central.any() else float("nan")
    ax.plot(rho, K, color="C0", lw=2, label=f"identified (worst central error {worst:.1f} %)")
    if model.has_intervals:
        lo_k, hi_k = model.elastic_stiffness_interval(rho, level)
        ax.fill_between(rho, lo_k, hi_k, color="C0", alpha=0.25, lw=0, label=f"{level:.0%} confidence band")
    ax.axvspan(c_lo, c_hi, color="C0", alpha=0.06, label=f"central {CENTRAL_FRACTION:.0%} of identified range")
    ax.set_xlabel("position (rad, + = dorsiflexion)")
    ax.set_ylabel("elastic stiffness K (N m/rad)")
    ax.set_title("elastic stiffness vs truth")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize="small", loc="upper left")
    return ax.figure


# --------------------------------------------------------------------------- diagnosis


def _two_line_bin(label) -> str:
    """A bin label "lo..hi" on two lines (legible without rotation at a report's width)."""
    text = str(label)
    parts = text.split("..")
    if len(parts) == 2 and " " not in text:
        return "\n".join(parts)
    import textwrap

    return "\n".join(textwrap.wrap(text, 10, break_long_words=False))


def plot_residual_diagnosis(diag, data, fig=None, ax=None):
    """Where a model fails (:class:`lpvpc.diagnosis.diagnose.Diagnosis` on ``data``): residual over
    time, residual RMS by position and by perturbation velocity, unexplained share per
    frequency band, cross-correlation of the residual with the inputs (each divided by its
    own 99 % band, so that one pair of lines at +-1 is every curve's band; negative lags:
    residual leads), and the candidates' gains. Laid out 3 rows x 2 columns at a width a
    report shows at its natural size (tick labels upright, at the default font size).
    ``ax``: a 3 x 2 array of axes to draw into (default: new ones in ``fig``). Returns the
    figure."""
    from matplotlib.figure import Figure

    if ax is not None:
        axes = np.asarray(ax).reshape(3, 2)
        fig = axes[0, 0].figure
    else:
        fig = fig or Figure(figsize=(9.6, 10.5))
        axes = fig.subplots(3, 2)
    t = np.asarray(data.time) - np.asarray(data.time)[0]
    y, r = np.asarray(data.torque), np.asarray(diag.residual)
    ax = axes[0, 0]
    ax.plot(t, y, color="0.75", lw=0.6, label="measured")
    ax.plot(t, r, color="C3", lw=0.6, label="residual")
    ax.set(xlabel="time (s)", ylabel="torque (N m)", title=f"VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.3g} N m")
    ax.legend(loc="upper right", fontsize="small")
    for ax, key in ((axes[0, 1], "position"), (axes[1, 0], "velocity")):
        bins = diag.where[key]["bins"]
        ax.bar(range(len(bins)), [b["residual_rms"] for b in bins], color="C3")
        ax.set_xticks(range(len(bins)), [_two_line_bin(b["bin"]) for b in bins], fontsize="small")
        ax.set(xlabel=diag.where[key]["by"], ylabel="residual RMS (N m)")
    ax = axes[1, 1]
    fb = diag.where["frequency"]
    ax.bar(range(len(fb)), [100 * b["unexplained_fraction"] for b in fb], color="C0")
    ax.set_xticks(range(len(fb)), [f"{b['band_hz'][0]:g}-\n{b['band_hz'][1]:g}" for b in fb], fontsize="small")
    ax.set(xlabel="band (Hz)", ylabel="unexplained power (%)", title="by frequency band")
    ax = axes[2, 0]
    for name, c in diag.where["cross_correlation"].items():
        if name in ("velocity", "delayed_velocity", "position") and c.get("band_99"):
            lags = np.linspace(c["lags_s"][0], c["lags_s"][1], len(c["ccf"]))
            ax.plot(lags, np.asarray(c["ccf"], dtype=float) / c["band_99"], label=name.replace("_", " "))
    ax.axhspan(-1.0, 1.0, color="0.9", label="99 % band")
    ax.axvline(0, color="k", lw=0.5)
    ax.set(xlabel="lag (s)", ylabel="correlation / its 99 % band", title="residual vs input")
    ax.legend(fontsize="small")
    ax = axes[2, 1]
    cands = [c for c in diag.candidates if c.available][:8]
    ax.barh(range(len(cands))[::-1], [c.vaf_gain for c in cands],
            color=["C2" if c.significant else "0.6" for c in cands])
    ax.set_yticks(range(len(cands))[::-1], [c.effect.replace("_", " ") for c in cands], fontsize="small")
    ax.axvline(diag.settings.get("min_gain", 0.0), color="k", ls=":", lw=0.8)
    ax.set(xlabel="held-out VAF gain (pp)", title="candidates (green: significant)")
    fig.tight_layout()
    return fig


def plot_ladder(steps, ax=None):
    """Held-out VAF (%) and RMSE (N m) of each model on the improve ladder. ``steps``: list
    of dicts with ``label``, ``heldout_vaf``, ``heldout_rmse``. Returns the figure (the
    RMSE is on a twin axis, ``fig.axes[-1]``).

    >>> fig = plot_ladder([{"label": "base model", "heldout_vaf": 97.4, "heldout_rmse": 0.30},
    ...                    {"label": "+ drift", "heldout_vaf": 97.8, "heldout_rmse": 0.28}])
    >>> [a.get_ylabel() for a in fig.axes]
    ['held-out VAF (%)', 'held-out RMSE (N m)']
    """
    ax = _new_axes(ax)
    x = np.arange(len(steps))
    ax.plot(x, [s["heldout_vaf"] for s in steps], "o-", color="C0")
    ax.set_ylabel("held-out VAF (%)", color="C0")
    ax2 = ax.twinx()
    ax2.plot(x, [s["heldout_rmse"] for s in steps], "s--", color="C3")
    ax2.set_ylabel("held-out RMSE (N m)", color="C3")
    ax.set_xticks(x)
    ax.set_xticklabels([s["label"] for s in steps], rotation=20, ha="right", fontsize=8)
    ax.set_title("held-out fit at each step")
    return ax.figure


def plot_residual_change(time, measured, before, after, labels=("before", "after"), fs=None, axes=None, ax=None):
    """Residuals (N m) before and after a step of the improve loop: over time (s, linear)
    and as power spectra. ``ax`` (or ``axes``): two axes to draw into. Returns the figure.

    A residual whose 10 Hz part an improvement removed:

    >>> t = np.arange(3000) / 100.0  # s
    >>> rng = np.random.default_rng(0)
    >>> after = 0.1 * rng.standard_normal(3000)  # N m
    >>> before = after + np.sin(2 * np.pi * 10 * t)
    >>> fig = plot_residual_change(t, 5 * np.sin(t), before, after, labels=("base", "+ effect"))
    >>> [a.get_xlabel() for a in fig.axes]
    ['time (s)', 'frequency (Hz)']
    """
    import scipy.signal

    axes = ax if ax is not None else axes
    if axes is None:
        from matplotlib.figure import Figure

        axes = Figure(figsize=(11, 3.5)).subplots(1, 2)
    t = np.asarray(time) - np.asarray(time)[0]
    ax = axes[0]
    ax.plot(t, before, lw=0.6, color="C3", label=f"residual {labels[0]}")
    ax.plot(t, after, lw=0.6, color="C2", label=f"residual {labels[1]}", alpha=0.8)
    ax.set(xlabel="time (s)", ylabel="torque (N m)")
    ax.legend(fontsize=8, loc="upper right")
    ax = axes[1]
    fs = fs or 1.0 / np.median(np.diff(t))
    for x, lab, c in ((measured, "measured", "0.6"), (before, labels[0], "C3"), (after, labels[1], "C2")):
        f, P = scipy.signal.welch(np.asarray(x), fs, nperseg=min(len(x), int(8 * fs)))
        ax.semilogy(f[1:], P[1:], color=c, label=lab)
    ax.set(xlabel="frequency (Hz)", ylabel="PSD (N^2 m^2/Hz)")
    ax.legend(fontsize=8)
    return ax.figure
