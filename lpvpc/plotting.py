"""The paper's figures (Sobhani Tehrani et al., EMBC 2014, Figs. 3-5) and a truth check.

Every function draws into the axes it is given (``ax``) or into a new figure when ``ax``
is None, and returns the axes it drew into. Nothing here calls ``plt.show()`` or selects
a backend: scripts and tests choose one (``matplotlib.use("Agg")`` for files).

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
    import matplotlib.pyplot as plt

    _, ax = plt.subplots(subplot_kw=subplot_kw or None)
    return ax


def _positions(model, n):
    lo, hi = model.scheduling_range
    return np.linspace(lo, hi, n)


def _position_colours(n):
    import matplotlib

    cmap = matplotlib.colormaps["viridis"]
    return [cmap(x) for x in np.linspace(0.0, 0.9, n)]


# --------------------------------------------------------------------------- Fig. 3


def plot_torque_fit(time, measured, prediction, ax=None, *, fig=None, window=None):
    """Measured vs predicted perturbation torque (N m) over time (s) (Fig. 3).

    ``prediction`` is a :class:`lpvpc.model.Prediction` (total, intrinsic, reflex) or an
    array of predicted total torque. Layout:

    - ``ax`` None: three stacked axes (total, intrinsic, reflex) in ``fig`` (a new figure
      if ``fig`` is None); returns the array of three axes;
    - ``ax`` a sequence of three axes: the same, drawn into them;
    - ``ax`` one axes: everything overlaid in it; returns it.

    ``window`` = (t0, t1) in s restricts the plot to that interval (the whole record
    is unreadable at 100 Hz over 2 minutes).
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
        return ax

    if ax is None:
        import matplotlib.pyplot as plt

        fig = fig if fig is not None else plt.figure(figsize=(9, 6.5))
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
    return axes


# --------------------------------------------------------------------------- Fig. 4


def plot_intrinsic_gain(model, ax=None, *, kind="image", n_freq=101, n_rho=61, positions=7):
    """Intrinsic gain |H(f, rho)| (N m/rad) over frequency 0..fs/2 (Hz) and position (rad)
    with the elastic stiffness K(rho) = gain at 0 Hz (Fig. 4).

    ``kind``:

    - "image" (default): colour map of the gain over position (x) and frequency (y); the
      elastic stiffness K(rho) is drawn on a second y-axis (right, N m/rad);
    - "curves": gain vs frequency for ``positions`` positions (the curves start at K(rho));
    - "surface": the paper's 3-D surface; ``ax`` must be a 3-D axes or None.
    """
    freqs = np.linspace(0.0, model.fs / 2, n_freq)
    if kind == "curves":
        ax = _new_axes(ax)
        rho = _positions(model, positions)
        gain = np.abs(model.intrinsic_frequency_response(freqs, rho))
        for r, g, c in zip(rho, gain, _position_colours(len(rho))):
            ax.plot(freqs, g, color=c, label=f"{r:+.2f} rad (K = {g[0]:.0f})")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("intrinsic gain (N m/rad)")
        ax.set_xlim(freqs[0], freqs[-1])
        ax.legend(title="position", fontsize="small", loc="upper left")
        ax.set_title("intrinsic stiffness gain")
        return ax

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
        return ax
    if kind != "image":
        raise ValueError(f"kind must be 'image', 'curves' or 'surface', got {kind!r}")

    from matplotlib.colors import LogNorm

    ax = _new_axes(ax)
    # Log colour scale: inertia dominates at high frequency (I w^2); the position dependence
    # of the low-frequency gain and of the resonance valley would vanish on a linear scale.
    positive = gain[gain > 0]
    norm = LogNorm(vmin=positive.min(), vmax=positive.max()) if positive.size else None
    mesh = ax.pcolormesh(rho, freqs, gain.T, shading="auto", cmap="viridis", norm=norm)
    ax.figure.colorbar(mesh, ax=ax, location="top", label="|H| (N m/rad, log scale)", fraction=0.05, pad=0.02)
    ax.set_xlabel("position rho (rad)")
    ax.set_ylabel("frequency (Hz)")
    twin = ax.twinx()
    twin.plot(rho, model.elastic_stiffness(rho), color="w", lw=2.5)
    twin.plot(rho, model.elastic_stiffness(rho), color="C3", lw=1.5, label="K(rho): gain at 0 Hz")
    twin.set_ylabel("elastic stiffness K (N m/rad)", color="C3")
    twin.tick_params(axis="y", colors="C3")
    twin.set_ylim(bottom=0)
    twin.legend(loc="upper left", fontsize="small")
    return ax


# --------------------------------------------------------------------------- Fig. 5


def plot_reflex_nonlinearity(model, ax=None, *, positions=7, velocity=None, truth=None):
    """Reflex static nonlinearity f(v, rho) (N m, steady reflex torque for a constant
    delayed velocity v in rad/s) for ``positions`` positions across the identified range
    (Fig. 5A). ``velocity`` defaults to the identified velocity range.

    ``truth``: optional object with ``reflex_gain(theta)`` and ``reflex_threshold(theta)``
    (e.g. :class:`lpvpc.simulate.SubjectParams`); its half-wave rectifiers are drawn dashed.
    """
    ax = _new_axes(ax)
    if velocity is None:
        velocity = np.linspace(*model.velocity_range, 201)
    velocity = np.asarray(velocity, dtype=float)
    rho = _positions(model, positions) if np.ndim(positions) == 0 else np.asarray(positions, dtype=float)
    curves = model.reflex_nonlinearity(velocity, rho)
    for r, f, c in zip(rho, curves, _position_colours(len(rho))):
        ax.plot(velocity, f, color=c, label=f"{r:+.2f} rad")
        if truth is not None:
            g, th = float(truth.reflex_gain(r)), float(truth.reflex_threshold(r))
            ax.plot(velocity, g * np.maximum(velocity - th, 0.0), color=c, ls="--", lw=0.9)
    ax.axhline(0.0, color="0.7", lw=0.6)
    ax.set_xlabel("delayed stretch velocity (rad/s)")
    ax.set_ylabel("steady reflex torque (N m)")
    ax.set_title("reflex nonlinearity" + (" (dashed: truth)" if truth is not None else ""))
    ax.legend(title="position", fontsize="small", loc="upper left")
    if model.fs < 500:  # 20 ms velocity pulses are smoothed at this rate (benchmarks: reflex_observability)
        ax.text(0.98, 0.02, f"seen on {model.fs:g} Hz velocity: the threshold is biased (a soft rectifier)",
                transform=ax.transAxes, ha="right", va="bottom", fontsize="x-small", color="0.35")
    return ax


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
    ax.set_title("reflex dynamics")
    ax.legend(fontsize="small")
    return ax


# --------------------------------------------------------------------------- truth check


def plot_stiffness_vs_truth(model, truth_theta, truth_K, ax=None):
    """Identified elastic stiffness K(rho) over the identified range against a known
    K(theta) (N m/rad vs rad); the central 80 % of the identified range, where K is
    judged, is shaded and the worst error there is given in the legend."""
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
    ax.axvspan(c_lo, c_hi, color="C0", alpha=0.08, label=f"central {CENTRAL_FRACTION:.0%} of identified range")
    ax.set_xlabel("position (rad, + = dorsiflexion)")
    ax.set_ylabel("elastic stiffness K (N m/rad)")
    ax.set_title("elastic stiffness vs truth")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize="small", loc="upper left")
    return ax


# --------------------------------------------------------------------------- diagnosis


def plot_residual_diagnosis(diag, data, fig=None):
    """Where a model fails (:class:`lpvpc.diagnose.Diagnosis` on ``data``): residual over
    time, residual RMS by position and by perturbation velocity, unexplained share per
    frequency band, and cross-correlation of the residual with the perturbation velocity
    and the delayed velocity (negative lags: residual leads). Returns the axes (2 x 3)."""
    import matplotlib.pyplot as plt

    fig = fig or plt.figure(figsize=(13, 7))
    axes = fig.subplots(2, 3)
    t = np.asarray(data.time) - np.asarray(data.time)[0]
    y, r = np.asarray(data.torque), np.asarray(diag.residual)
    ax = axes[0, 0]
    ax.plot(t, y, color="0.75", lw=0.6, label="measured")
    ax.plot(t, r, color="C3", lw=0.6, label="residual")
    ax.set(xlabel="time (s)", ylabel="torque (N m)", title=f"VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.3g} N m")
    ax.legend(loc="upper right", fontsize=8)
    for ax, key in ((axes[0, 1], "position"), (axes[0, 2], "velocity")):
        bins = diag.where[key]["bins"]
        ax.bar(range(len(bins)), [b["residual_rms"] for b in bins], color="C3")
        ax.set_xticks(range(len(bins)))
        ax.set_xticklabels([b["bin"] for b in bins], rotation=35, ha="right", fontsize=7)
        ax.set(ylabel="residual RMS (N m)", title=f"by {diag.where[key]['by']}")
    ax = axes[1, 0]
    fb = diag.where["frequency"]
    ax.bar(range(len(fb)), [100 * b["unexplained_fraction"] for b in fb], color="C0")
    ax.set_xticks(range(len(fb)))
    ax.set_xticklabels([f"{b['band_hz'][0]:g}-{b['band_hz'][1]:g}" for b in fb], fontsize=7)
    ax.set(xlabel="band (Hz)", ylabel="unexplained power (%)", title="by frequency band")
    ax = axes[1, 1]
    for name, c in diag.where["cross_correlation"].items():
        if name in ("velocity", "delayed_velocity", "position"):
            lags = np.linspace(c["lags_s"][0], c["lags_s"][1], len(c["ccf"]))
            ax.plot(lags, c["ccf"], label=name)
            ax.axhspan(-c["band_99"], c["band_99"], color="0.9")
    ax.axvline(0, color="k", lw=0.5)
    ax.set(xlabel="lag (s)", ylabel="correlation", title="residual vs input")
    ax.legend(fontsize=7)
    ax = axes[1, 2]
    cands = [c for c in diag.candidates if c.available][:8]
    ax.barh(range(len(cands))[::-1], [c.vaf_gain for c in cands],
            color=["C2" if c.significant else "0.6" for c in cands])
    ax.set_yticks(range(len(cands))[::-1])
    ax.set_yticklabels([c.effect for c in cands], fontsize=7)
    ax.axvline(diag.settings.get("min_gain", 0.0), color="k", ls=":", lw=0.8)
    ax.set(xlabel="held-out VAF gain (pp)", title="candidates (green: significant)")
    fig.tight_layout()
    return axes


def plot_ladder(steps, ax=None):
    """Held-out VAF (%) and RMSE (N m) of each model on the improve ladder. ``steps``: list
    of dicts with ``label``, ``heldout_vaf``, ``heldout_rmse``. Returns (ax, twin ax)."""
    ax = _new_axes(ax)
    x = np.arange(len(steps))
    ax.plot(x, [s["heldout_vaf"] for s in steps], "o-", color="C0")
    ax.set_ylabel("held-out VAF (%)", color="C0")
    ax2 = ax.twinx()
    ax2.plot(x, [s["heldout_rmse"] for s in steps], "s--", color="C3")
    ax2.set_ylabel("held-out RMSE (N m)", color="C3")
    ax.set_xticks(x)
    ax.set_xticklabels([s["label"] for s in steps], rotation=20, ha="right", fontsize=8)
    ax.set_title("improve: the error falls as effects are added")
    return ax, ax2


def plot_residual_change(time, measured, before, after, labels=("before", "after"), fs=None, axes=None):
    """Residuals (N m) before and after a step of the improve loop: over time and as power
    spectra. Returns the two axes."""
    import matplotlib.pyplot as plt
    import scipy.signal

    if axes is None:
        _, axes = plt.subplots(1, 2, figsize=(11, 3.5))
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
    return axes
