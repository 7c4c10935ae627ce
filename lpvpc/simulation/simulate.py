"""The virtual subject: a physics-based ankle on a stiff position servo.

Simulates the two trials the LPV-PC method needs (Sobhani Tehrani, Jalaleddini, Kearney,
EMBC 2014): an unperturbed trial (UT) that follows a slow position trajectory and a
perturbed trial (PT) on the same trajectory with a PRALDS perturbation added. Everything
runs at ``fs_sim`` = 1 kHz and is optionally decimated to the output rate.

Units are SI everywhere: time s, angle rad (positive = dorsiflexion), angular velocity
rad/s, acceleration rad/s^2, torque N m (positive = the torque that resists
dorsiflexion, i.e. the same sign as ``K * angle``), stiffness N m/rad, viscosity
N m s/rad, inertia kg m^2.

The chain, one function per physical element::

    trajectory (multilevel_trajectory | novel_trajectory)  --+
    pralds (PT only) ----------------------------------------+--> command
    command --> servo --> theta, velocity, acceleration        (stiff: torque does not
                                                                 deflect the servo)
    intrinsic_torque = I*acc + B*vel + E(theta)
    reflex_torque    = LP_2nd( G(theta) * max(vel(t - delay) - th(theta), 0) )
    torque           = intrinsic + reflex + coloured_noise

    emg              = envelope(tonic + activation + reflex drive / emg_reflex_torque) + noise

Both trials record an EMG envelope (V): tonic activation in both, reflex-evoked bursts
(~40 ms after each velocity pulse, with the reflex's gain and threshold) in the perturbed
one, measurement noise. Effects the base LPV-PC model does not contain are switchable by
name through the :data:`~lpvpc.simulation.simulated_effects.EFFECTS` registry; each has its diagnosis-catalog counterpart of
the same name in :data:`lpvpc.models.effects.CATALOG`, except those marked "outside the diagnosis
catalog" (they test what the diagnosis says of effects it has no entry for).

Where each part lives (every public name is importable from here as before):

- :mod:`lpvpc.simulation.subject`: :class:`~lpvpc.simulation.subject.SubjectParams`, the subject's parameters and
  its stiffness and reflex curves;
- :mod:`lpvpc.simulation.trajectories`: position trajectories and perturbation designs (elements 1-2);
- :mod:`lpvpc.simulation.physics`: the servo, intrinsic mechanics, stretch reflex and torque noise
  (elements 3-6);
- :mod:`lpvpc.simulation.emg`: the EMG envelope from activation and reflex drive;
- :mod:`lpvpc.simulation.simulated_effects`: the :data:`~lpvpc.simulation.simulated_effects.EFFECTS` registry of effects the base model lacks;
- this module: the pair (:func:`simulate_pair`) and the dataset files (:func:`write_dataset`).

Public API: :class:`~lpvpc.simulation.subject.SubjectParams`, :class:`SimulatedPair`, :func:`simulate_pair`,
:func:`write_dataset`, :data:`~lpvpc.simulation.simulated_effects.EFFECTS`, and the element functions
:func:`~lpvpc.simulation.trajectories.multilevel_trajectory`, :func:`~lpvpc.simulation.trajectories.novel_trajectory`, :func:`~lpvpc.simulation.trajectories.pralds`, :func:`~lpvpc.simulation.trajectories.lab_pulses`, :func:`~lpvpc.simulation.trajectories.prbs`, :func:`~lpvpc.simulation.physics.servo`,
:func:`~lpvpc.simulation.physics.intrinsic_torque`, :func:`~lpvpc.simulation.physics.reflex_torque`, :func:`~lpvpc.simulation.physics.coloured_noise`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io import Trial, decimate_signal, write_trial_csv
from .emg import EMG_UNITS, _rms, emg_envelope
from ..models.model import vaf
from .physics import (SENSOR_OVERSAMPLING, coloured_noise, delay_signal, intrinsic_torque, recorded_acceleration,
    reflex_lowpass_coefficients, reflex_torque, servo)
from .simulated_effects import EFFECTS, CustomEffect, TrialState, _check_effects, effect_entry
from .subject import FS_SIM, SubjectParams, THETA_DF, THETA_PF
from .trajectories import (PERTURBATIONS, _TRAJECTORIES, lab_pulses, multilevel_trajectory, novel_trajectory, pralds,
    prbs, stationary_trajectory)


# ---------------------------------------------------------------------------------------
# The pair
# ---------------------------------------------------------------------------------------


@dataclass
class SimulatedPair:
    """A simulated PT/UT pair at the output rate (:func:`simulate_pair` makes it).

    Parameters
    ----------
    pt, ut : lpvpc.io.trial.Trial
        Noisy trials (channels 'command' and 'emg', the EMG envelope in ``emg_unit``).
    pt_clean, ut_clean : lpvpc.io.trial.Trial
        The same with noise-free torque.
    truth : dict
        JSON-serialisable parameters, curves and measured quantities.
    components : dict
        Noise-free torques (N m) 'pt_intrinsic', 'pt_reflex', 'ut_intrinsic', 'ut_reflex'.
    activation : dict, optional
        Each trial's true background activation (1; tonic level plus any slow activation,
        the EMG's drive without the reflex bursts), {'PT': ..., 'UT': ...} at the output
        rate.

    Examples
    --------
    >>> pair = simulate_pair("multilevel", seed=0, duration=10.0, fs_out=100.0)
    >>> pair.pt.fs, len(pair.pt.time), sorted(pair.pt.channels)  # Hz, samples, recorded channels
    (100.0, 1000, ['command', 'emg'])
    >>> bool(np.allclose(pair.pt_clean.position, pair.pt.position))  # noise is in the torque only
    True
    """

    pt: Trial
    ut: Trial
    pt_clean: Trial
    ut_clean: Trial
    truth: dict
    components: dict
    activation: dict = field(default_factory=dict)


def _simulate_trial(command, slow, perturbed, fs, params, effects, rng):
    """Physics of one trial at the simulation rate: returns kinematics, torques, channels.
    ``slow`` is the unperturbed trial's result (None when simulating the UT itself)."""
    theta, vel, _ = servo(command, fs, params)
    acc = recorded_acceleration(command, fs, params)  # band-limited, as recorded (not the jumps' samples)
    t = np.arange(len(command)) / fs
    st = TrialState(t=t, theta=theta, vel=vel, acc=acc, command=command,
                    slow_velocity=vel if slow is None else slow["vel"],
                    slow_theta=theta if slow is None else slow["theta"],
                    perturbed=perturbed, fs=fs, params=params, rng=rng,
                    ut_activation=None if slow is None else slow["slow_activation"])
    info = {}
    for e in effects:
        name, _, apply = effect_entry(e)
        info[name] = apply(st)
    tq_i = intrinsic_torque(theta, vel, acc, params, stiffness_scale=st.stiffness_scale,
                            viscosity_scale=st.viscosity_scale, extra=st.extra_torque)
    tq_r, z = reflex_torque(theta, vel, fs, params, gain_scale=st.reflex_gain_scale, wn=st.reflex_wn,
                            delay=st.reflex_delay)
    return {"theta": theta, "vel": vel, "intrinsic": tq_i, "reflex": tq_r, "reflex_drive": z,
            "activation": params.emg_tonic + st.activation, "slow_activation": st.activation,
            "channels": st.channels, "effects": info}


def simulate_pair(trajectory: str = "multilevel", *, seed: int = 0, duration: float = 120.0,
                  fs_out: float = 1000.0, snr_db: float = 18.0,
                  perturbation_amplitude: float = 0.04, params: SubjectParams | None = None,
                  effects=(), emg_unit: str = "V", perturbation: str = "pralds",
                  stiffness_family: str | None = None, position_noise: float = 0.0) -> SimulatedPair:
    """Simulate a perturbed (PT) and an unperturbed (UT) trial on the same trajectory.

    Position has no sensor noise by default (``position_noise``: white noise of that RMS in
    each trial's recorded position). Both trials carry channel 'emg'
    (:func:`~lpvpc.simulation.emg.emg_envelope`: tonic activation in both, reflex-evoked
    bursts, noise).

    Parameters
    ----------
    trajectory : {"multilevel", "novel", "stationary"}, default "multilevel"
        "multilevel" (identification), "novel" (held-out shapes that also leave the
        identified range briefly) or "stationary" (one position, -0.1 rad).
    seed : int, default 0
        Selects all random streams (trajectory, PRALDS, noise, effects); the novel
        trajectory uses a different stream than the multilevel one for the same seed.
    duration : float, default 120.0
        Length of each trial (s).
    fs_out : float, default 1000.0
        Output rate (Hz); must divide 1000 (1000: no decimation; 100:
        ``scipy.signal.decimate(q=10, ftype='fir', zero_phase=True)``).
    snr_db : float or None, default 18.0
        SNR of the perturbation torque, 10 log10(var(PT-UT clean) / var(PT-UT noise)),
        exact at the output rate (``inf`` or None: no noise).
    perturbation_amplitude : float, default 0.04
        Perturbation levels uniform in +-amplitude (rad).
    params : lpvpc.simulation.subject.SubjectParams, optional
        The subject; default ``SubjectParams()``.
    effects : tuple, default ``()``
        Names from :data:`~lpvpc.simulation.simulated_effects.EFFECTS` or
        :class:`lpvpc.simulation.simulated_effects.CustomEffect` objects.
    emg_unit : {"V", "mV", "uV"}, default "V"
        The unit of the 'emg' channel.
    perturbation : {"pralds", "lab_pulses", "prbs"}, default "pralds"
        :func:`~lpvpc.simulation.trajectories.pralds`,
        :func:`~lpvpc.simulation.trajectories.lab_pulses` (the lab pilot trial's design:
        every step large) or :func:`~lpvpc.simulation.trajectories.prbs` (+-amplitude
        switching every 50-150 ms, no quiet windows).
    stiffness_family : str, optional
        The subject's elastic stiffness shape (:data:`lpvpc.simulation.subject.STIFFNESS_FAMILIES`;
        None: that of ``params``, "standard" by default), set with
        :meth:`SubjectParams.with_stiffness_family <lpvpc.simulation.subject.SubjectParams.with_stiffness_family>`;
        it draws no random numbers, so a seed gives the same streams in every family.
    position_noise : float, default 0.0
        RMS (rad) of white noise added to each trial's recorded position at the output rate
        (the sensor's noise floor; the joint moves as without it, and ``pt_clean`` and
        ``ut_clean`` record the same noisy position). The lab's pilot trial's 1 kHz PT - UT
        position has a floor of about 7e-5 rad (5e-5 in each trial; docs/design_notes.md,
        "Position noise floor"). Its streams come after the others: the rest of the pair is
        the same with or without it.

    Returns
    -------
    SimulatedPair
        ``pt`` and ``ut`` (:class:`~lpvpc.io.trial.Trial`, with channels 'emg' and
        'command') and ``truth`` (the subject's curves and the clean torque components).

    Raises
    ------
    ValueError
        An unknown trajectory, perturbation, effect or EMG unit, a rate that does not
        divide 1000 Hz, fewer than 100 output samples, or a negative position noise.

    Examples
    --------
    >>> sim = simulate_pair("multilevel", seed=0, duration=10.0, fs_out=100.0)
    >>> sim.pt.fs, len(sim.pt.torque), sorted(sim.pt.channels)
    (100.0, 1000, ['command', 'emg'])
    """
    if emg_unit not in EMG_UNITS:
        raise ValueError(f"unknown EMG unit {emg_unit!r}; use one of {sorted(EMG_UNITS)}")
    if trajectory not in _TRAJECTORIES:
        raise ValueError(f"unknown trajectory {trajectory!r}; use one of {sorted(_TRAJECTORIES)}")
    if perturbation not in PERTURBATIONS:
        raise ValueError(f"unknown perturbation {perturbation!r}; use one of {sorted(PERTURBATIONS)}")
    if not (np.isfinite(position_noise) and position_noise >= 0):
        raise ValueError(f"position_noise={position_noise} must be a finite RMS >= 0 (rad)")
    effects = _check_effects(effects)
    params = params or SubjectParams()
    if stiffness_family is not None:
        params = params.with_stiffness_family(stiffness_family)
    fs = FS_SIM
    q = fs / fs_out
    if fs_out <= 0 or abs(q - round(q)) > 1e-9:
        raise ValueError(f"fs_out={fs_out} Hz must divide the simulation rate {fs} Hz")
    q = int(round(q))
    if duration * fs_out < 100:
        raise ValueError(f"duration {duration} s is too short (need >= 100 output samples)")

    code, make_traj = _TRAJECTORIES[trajectory]
    ss = np.random.SeedSequence([int(seed), code])
    r_traj, r_pert, r_npt, r_nut, r_ept, r_eut = (np.random.default_rng(s) for s in ss.spawn(6))
    r_mpt, r_mut = (np.random.default_rng(s) for s in ss.spawn(2))  # EMG noise (after the others: same streams)
    r_ppt, r_put = (np.random.default_rng(s) for s in ss.spawn(2))  # position sensor noise (likewise)

    traj = make_traj(duration, fs, r_traj)
    pert = PERTURBATIONS[perturbation](duration, fs, r_pert, amplitude=perturbation_amplitude)
    cmd = {"UT": traj, "PT": traj + pert}
    ut = _simulate_trial(cmd["UT"], None, False, fs, params, effects, r_eut)
    pt = _simulate_trial(cmd["PT"], ut, True, fs, params, effects, r_ept)
    for sim, r in ((ut, r_mut), (pt, r_mpt)):
        sim["channels"]["emg"] = EMG_UNITS[emg_unit] * emg_envelope(sim["activation"], sim["reflex_drive"], fs, r, params)

    def out(x):  # to the output rate
        return decimate_signal(x, q)

    n = len(traj)
    t_out = (np.arange(n) / fs)[::q]
    comp = {"pt_intrinsic": out(pt["intrinsic"]), "pt_reflex": out(pt["reflex"]),
            "ut_intrinsic": out(ut["intrinsic"]), "ut_reflex": out(ut["reflex"])}
    clean = {"PT": comp["pt_intrinsic"] + comp["pt_reflex"],
             "UT": comp["ut_intrinsic"] + comp["ut_reflex"]}
    pos = {"PT": out(pt["theta"]), "UT": out(ut["theta"])}

    # Noise: independent coloured noise in each trial, one common scale chosen so the
    # perturbation torque (PT - UT) has exactly the requested SNR at the output rate
    # (decimation is linear, so scaling after decimating is the same as before).
    noise_pt = out(coloured_noise(n, fs, r_npt, params))
    noise_ut = out(coloured_noise(n, fs, r_nut, params))
    d_clean = clean["PT"] - clean["UT"]
    if snr_db is None or np.isinf(snr_db):
        scale = 0.0
    else:
        scale = float(np.sqrt(np.var(d_clean) / (np.var(noise_pt - noise_ut) * 10 ** (snr_db / 10))))
    noisy = {"PT": clean["PT"] + scale * noise_pt, "UT": clean["UT"] + scale * noise_ut}
    d_noisy = noisy["PT"] - noisy["UT"]
    recorded = {k: pos[k] + position_noise * r.standard_normal(len(pos[k])) for k, r in (("PT", r_ppt), ("UT", r_put))}

    def trial(key, torque, sim):
        ch = {"command": out(cmd[key])}
        ch.update({k: out(v) for k, v in sim["channels"].items()})
        ch["emg"] = np.maximum(ch["emg"], 0.0)  # an envelope: the decimation filter's ringing clipped
        return Trial(time=t_out.copy(), position=recorded[key].copy(), torque=torque, channels=ch,
                     name=f"{trajectory}_{key}")

    eff_truth = [{"name": name, "description": desc, "parameters": pt["effects"][name]}
                 for name, desc, _ in map(effect_entry, effects)]
    d_vel = out(pt["vel"] - ut["vel"])
    d_int = comp["pt_intrinsic"] - comp["ut_intrinsic"]
    d_ref = comp["pt_reflex"] - comp["ut_reflex"]
    truth = {
        "trajectory": trajectory,
        "seed": int(seed),
        "duration": float(duration),
        "fs_sim": fs,
        "fs_out": float(fs_out),
        "snr_db": None if snr_db is None else float(snr_db),
        "perturbation_amplitude": float(perturbation_amplitude),
        "perturbation": perturbation,
        "params": params.to_dict(),
        "curves": params.curves(),
        "reflex_delay": params.reflex_delay,
        "reflex_wn": params.reflex_wn,
        "reflex_zeta": params.reflex_zeta,
        "effects": eff_truth,
        "noise_scale": scale,
        "position_noise": float(position_noise),
        "units": {"time": "s", "position": "rad", "torque": "N m", "command": "rad", "emg": emg_unit},
        "emg_unit": emg_unit,
        # measured on this record at the output rate; RMS values are about zero
        "measured": {
            "snr_db": float(10 * np.log10(np.var(d_clean) / np.var(d_noisy - d_clean)))
            if scale > 0 else float("inf"),
            "vaf_ceiling": vaf(d_noisy, d_clean),
            "perturbation_torque_rms": _rms(d_clean - d_clean.mean()),
            "perturbation_intrinsic_rms": _rms(d_int - d_int.mean()),
            "perturbation_reflex_rms": _rms(d_ref),
            "ut_reflex_rms": _rms(comp["ut_reflex"]),
            "pt_reflex_rms": _rms(comp["pt_reflex"]),
            "ut_to_perturbation_reflex_rms_ratio": _rms(comp["ut_reflex"]) / max(_rms(d_ref), 1e-12),
            "ut_reflex_active_fraction": float(np.mean(np.abs(comp["ut_reflex"]) > 0.01)),
            "noise_rms": _rms(d_noisy - d_clean),
            "peak_perturbation_velocity": float(np.max(np.abs(d_vel))),
            "peak_ut_velocity": float(np.max(np.abs(out(ut["vel"])))),
            "scheduling_range": [float(pos["UT"].min()), float(pos["UT"].max())],
            "pt_position_range": [float(pos["PT"].min()), float(pos["PT"].max())],
        },
    }
    if truth["measured"]["snr_db"] == float("inf"):
        truth["measured"]["snr_db"] = None  # JSON has no infinity
    pair = SimulatedPair(
        pt=trial("PT", noisy["PT"], pt), ut=trial("UT", noisy["UT"], ut),
        pt_clean=trial("PT", clean["PT"], pt), ut_clean=trial("UT", clean["UT"], ut),
        truth=truth, components=comp, activation={"PT": out(pt["activation"]), "UT": out(ut["activation"])})
    return pair


def _save_truth_npz(path, pair: SimulatedPair):
    from ..io.outputs import atomic_path

    c = pair.components
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # a file object: savez adds no suffix
        np.savez_compressed(
            fh, time=pair.pt.time,
            pt_position=pair.pt.position, ut_position=pair.ut.position,
            pt_torque_clean=pair.pt_clean.torque, ut_torque_clean=pair.ut_clean.torque,
            perturbation_intrinsic=c["pt_intrinsic"] - c["ut_intrinsic"],
            perturbation_reflex=c["pt_reflex"] - c["ut_reflex"],
            **c)


def write_dataset(out_dir, *, seed: int = 0, fs_out: float = 1000.0, snr_db: float = 18.0,
                  effects=(), duration: float = 120.0, params: SubjectParams | None = None,
                  perturbation: str = "pralds", stiffness_family: str | None = None,
                  emg_unit: str = "V", perturbation_amplitude: float = 0.04, extra_truth: dict | None = None) -> dict:
    """Write an identification pair and a novel (held-out) pair with their truth.

    Files in ``out_dir``: ident_PT.csv, ident_UT.csv, novel_PT.csv, novel_UT.csv
    (header ``time,position,torque[,emg],command``; s, rad, N m, rad), truth.json
    (parameters, curves, per-pair truth) and truth_ident.npz / truth_novel.npz (time,
    positions, clean PT/UT torques, the four components and the perturbation intrinsic
    and reflex torques, all at the output rate).

    Parameters
    ----------
    out_dir : str or pathlib.Path
        The folder to write (created).
    seed, fs_out, snr_db, effects, duration, params, perturbation, stiffness_family, emg_unit, perturbation_amplitude
        As in :func:`simulate_pair` (``emg_unit``: the 'emg' column's unit).
    extra_truth : dict, optional
        Entries added to truth.json (e.g. the population subject's description).

    Returns
    -------
    dict
        {file stem: pathlib.Path} of every file written.

    Raises
    ------
    ValueError
        As :func:`simulate_pair`.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     files = write_dataset(folder, duration=10.0, fs_out=100.0)
    ...     sorted(files)[:4], files["ident_PT"].read_text().splitlines()[0]
    (['ident_PT', 'ident_UT', 'novel_PT', 'novel_UT'], 'time,position,torque,emg,command')
    """
    params = params or SubjectParams()
    if stiffness_family is not None:
        params = params.with_stiffness_family(stiffness_family)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths, truth = {}, {"params": params.to_dict(), "curves": params.curves(),
                        "units": {"time": "s", "position": "rad", "torque": "N m",
                                  "command": "rad", "emg": emg_unit}}
    truth.update(extra_truth or {})
    for key, kind in (("ident", "multilevel"), ("novel", "novel")):
        pair = simulate_pair(kind, seed=seed, duration=duration, fs_out=fs_out, snr_db=snr_db,
                             params=params, effects=effects, perturbation=perturbation, emg_unit=emg_unit,
                             perturbation_amplitude=perturbation_amplitude)
        for which, tr in (("PT", pair.pt), ("UT", pair.ut)):
            p = out_dir / f"{key}_{which}.csv"
            write_trial_csv(tr, p)
            paths[f"{key}_{which}"] = p
        p = out_dir / f"truth_{key}.npz"
        _save_truth_npz(p, pair)
        paths[f"truth_{key}"] = p
        truth[key] = pair.truth
    p = out_dir / "truth.json"
    from ..io.outputs import write_text

    write_text(p, json.dumps(truth, indent=1))
    paths["truth"] = p
    return paths
