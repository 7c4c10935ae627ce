"""The actuator FMU (lpvpc/export/c/actuator): known physical responses, an independent check of the
discretisation, parameters, and a 2-minute record. Units: rad, rad/s, rad/s^2, N m, kg m^2."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy.linalg import expm

import fmpy
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy.fmi3 import FMU3Slave

from lpvpc.export.actuator import ACTUATOR_DEFAULTS, ACTUATOR_STEP, build_actuator_fmu

POS, VEL, ACC, CMD, LOAD = 1, 2, 3, 4, 5
PARAM = {name: 6 + i for i, name in enumerate(ACTUATOR_DEFAULTS)}


class Actuator:
    """One actuator instance driven through fmpy (FMI 2 or 3), with its log messages."""

    def __init__(self, unzipdir, md, **params):
        self.v = 2 if md.fmiVersion == "2.0" else 3
        self.logs = []
        cls = FMU2Slave if self.v == 2 else FMU3Slave
        self.fmu = cls(guid=md.guid, unzipDirectory=str(unzipdir),
                       modelIdentifier=md.coSimulation.modelIdentifier, instanceName="actuator")
        if self.v == 2:
            def log(env, inst, status, cat, msg):
                self.logs.append(msg.decode())
            self._cb = fmi2CallbackFunctions()
            self._cb.logger = fmi2CallbackLoggerTYPE(log)
            self._cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
            self._cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
            self._log = log
            self.fmu.instantiate(callbacks=self._cb)
            self.fmu.setupExperiment(startTime=0.0)
        else:
            self.fmu.instantiate(logMessage=lambda env, status, cat, msg: self.logs.append(msg.decode()))
        self.get = self.fmu.getReal if self.v == 2 else self.fmu.getFloat64
        self.set = self.fmu.setReal if self.v == 2 else self.fmu.setFloat64
        if self.v == 2:
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=0.0)
        if params:
            self.set([PARAM[k] for k in params], [float(x) for x in params.values()])
        self.t = 0.0

    def start(self):
        self.fmu.exitInitializationMode()
        return self

    def run(self, command, load, h=ACTUATOR_STEP):
        """Apply command[k], load[k] at t_k, step h; return outputs after each step (n x 3)."""
        out = np.empty((len(command), 3))
        for k in range(len(command)):
            self.set([CMD, LOAD], [float(command[k]), float(load[k])])
            self.fmu.doStep(self.t, h)
            self.t += h
            out[k] = self.get([POS, VEL, ACC])
        return out

    def free(self):
        self.fmu.freeInstance()


@pytest.fixture(scope="module", params=[2, 3], ids=["fmi2", "fmi3"])
def fmu(request, tmp_path_factory):
    path = build_actuator_fmu(tmp_path_factory.mktemp("act") / f"actuator{request.param}.fmu",
                              fmi_version=request.param)
    md = read_model_description(str(path))
    return extract(str(path), unzipdir=str(tmp_path_factory.mktemp("unzip"))), md


def make(fmu, **params) -> Actuator:
    return Actuator(*fmu, **params).start()


def reference_matrices(p, h):
    """Independent discretisation of the README equations with scipy's expm (tests only)."""
    wn, z, J, K, zc = (2 * math.pi * p["servo_bandwidth"], p["servo_damping"], p["footplate_inertia"],
                       p["servo_stiffness"], p["coupling_damping"])
    Bc = 2 * zc * math.sqrt(K * J)
    A = np.array([[0, 1, 0, 0], [-wn**2, -2 * z * wn, 0, 0], [0, 0, 0, 1], [K / J, Bc / J, -K / J, -Bc / J]])
    B = np.array([[0, 0], [wn**2, 0], [0, 0], [0, -1 / J]])
    Maug = np.zeros((6, 6))
    Maug[:4, :4], Maug[:4, 4:] = A, B
    E = expm(Maug * h)
    C = np.array([[0, 0, 1, 0], [0, 0, 0, 1], A[3]])
    D = np.array([[0, 0], [0, 0], B[3]])
    return E[:4, :4], E[:4, 4:], C, D


# ----------------------------------------------------------------------------- tests


def test_build_is_cached(tmp_path):
    t1, t2 = {}, {}
    p = build_actuator_fmu(tmp_path / "a.fmu", timings=t1)
    build_actuator_fmu(p, timings=t2)
    assert t1["reused"] is False and t2["reused"] is True
    assert t2["total"] < t1["total"]


def test_default_path_is_a_user_cache_not_the_package(tmp_path, monkeypatch):
    # An installed package folder may be read-only: the default build goes to a cache.
    monkeypatch.setenv("LPVPC_CACHE", str(tmp_path / "cache"))
    p = build_actuator_fmu()
    assert p == tmp_path / "cache" / "fmus" / "actuator_fmi2.fmu" and p.is_file()


def test_initial_state_and_direct_feedthrough(fmu):
    a = make(fmu, initial_position=-0.2)
    assert a.get([POS, VEL, ACC]) == [-0.2, 0.0, 0.0]
    a.set([CMD, LOAD], [-0.2, 2.0])  # load torque acts on the footplate immediately
    pos, vel, acc = a.get([POS, VEL, ACC])
    assert pos == -0.2 and vel == 0.0
    assert acc == pytest.approx(-2.0 / ACTUATOR_DEFAULTS["footplate_inertia"], rel=1e-12)
    a.free()


def test_step_response_matches_the_servo_bandwidth(fmu):
    a = make(fmu)
    n = 300
    y = a.run(np.full(n, 0.1), np.zeros(n))
    t = ACTUATOR_STEP * np.arange(1, n + 1)
    pos = y[:, 0] / 0.1
    # second-order servo with wn = 2 pi 40 Hz, zeta = 0.7: overshoot 4.6 %, 10-90 % rise 8.5 ms;
    # the footplate mode (159 Hz) adds a small lag
    rise = np.interp(0.9, pos[: np.argmax(pos)], t[: np.argmax(pos)]) - \
        np.interp(0.1, pos[: np.argmax(pos)], t[: np.argmax(pos)])
    wn = 2 * math.pi * ACTUATOR_DEFAULTS["servo_bandwidth"]
    assert rise == pytest.approx(2.137 / wn, rel=0.15)
    assert pos.max() - 1 == pytest.approx(0.046, abs=0.015)
    a.free()


def test_gain_at_the_bandwidth(fmu):
    a = make(fmu)
    f = ACTUATOR_DEFAULTS["servo_bandwidth"]
    t = ACTUATOR_STEP * np.arange(1000)
    y = a.run(0.01 * np.sin(2 * np.pi * f * t), np.zeros_like(t))
    tt = t[500:] + ACTUATOR_STEP  # outputs are at t_k + h
    X = np.column_stack([np.sin(2 * np.pi * f * tt), np.cos(2 * np.pi * f * tt)])
    coef, *_ = np.linalg.lstsq(X, y[500:, 0], rcond=None)
    gain = np.hypot(*coef) / 0.01
    # servo alone: 1/(2 zeta) = 0.714 at wn; the footplate mode (159 Hz, zeta_c 0.7) adds
    # |(K + jw Bc)/(K - J w^2 + jw Bc)| = 1.06 at 40 Hz; the command's ZOH changes < 0.3 %
    w = 2 * np.pi * f
    J, K = ACTUATOR_DEFAULTS["footplate_inertia"], ACTUATOR_DEFAULTS["servo_stiffness"]
    Bc = 2 * ACTUATOR_DEFAULTS["coupling_damping"] * np.sqrt(K * J)
    footplate = abs((K + 1j * w * Bc) / (K - J * w**2 + 1j * w * Bc))
    servo = 1 / (2 * ACTUATOR_DEFAULTS["servo_damping"])
    assert gain == pytest.approx(servo * footplate, rel=0.01)
    assert 0.68 < gain < 0.8  # about -3 dB: the bandwidth is what the parameter says
    a.free()


@pytest.mark.parametrize("stiffness", [ACTUATOR_DEFAULTS["servo_stiffness"], 5e3])
def test_static_deflection_is_load_over_stiffness(fmu, stiffness):
    a = make(fmu, servo_stiffness=stiffness, initial_position=0.2)
    y = a.run(np.full(500, 0.2), np.full(500, 20.0))
    deflection = 0.2 - y[-1, 0]
    assert deflection == pytest.approx(20.0 / stiffness, rel=0.01)
    assert abs(y[-1, 1]) < 1e-9 and abs(y[-1, 2]) < 1e-6
    a.free()


def test_steady_state_equals_command(fmu):
    a = make(fmu)
    y = a.run(np.full(1000, -0.35), np.zeros(1000))
    assert abs(y[-1, 0] + 0.35) < 1e-12 and abs(y[-1, 1]) < 1e-10
    a.free()


def test_matches_an_independent_discretisation(fmu):
    p = dict(ACTUATOR_DEFAULTS, servo_bandwidth=33.0, footplate_inertia=0.03, initial_position=0.05)
    a = make(fmu, **{k: p[k] for k in ("servo_bandwidth", "footplate_inertia", "initial_position")})
    rng = np.random.default_rng(7)
    n = 400
    cmd = 0.05 + np.repeat(rng.uniform(-0.04, 0.04, n // 20), 20)
    load = rng.normal(0, 5, n)
    y = a.run(cmd, load)
    Phi, Gam, C, D = reference_matrices(p, ACTUATOR_STEP)
    x = np.array([0.05, 0, 0.05, 0])
    ref = np.empty_like(y)
    for k in range(n):
        x = Phi @ x + Gam @ np.array([cmd[k], load[k]])
        ref[k] = C @ x + D @ np.array([cmd[k], load[k]])
    scale = np.abs(ref).max(axis=0)
    rel = np.abs(y - ref).max(axis=0) / scale
    assert np.all(rel <= 1e-10), rel
    a.free()


def test_communication_step_multiples_give_the_same_trajectory(fmu):
    a, b = make(fmu), make(fmu)
    ya = a.run(np.full(50, 0.1), np.full(50, 3.0), h=0.01)
    yb = b.run(np.full(500, 0.1), np.full(500, 3.0), h=0.001)
    np.testing.assert_allclose(ya, yb[9::10], rtol=1e-12, atol=1e-12)
    a.free()
    b.free()


def test_very_stiff_footplate_is_stable(fmu):
    # footplate mode sqrt(1e6/0.005) = 14,000 rad/s: |lambda| h = 14, far beyond explicit RK4
    a = make(fmu, servo_stiffness=1e6, footplate_inertia=0.005)
    y = a.run(np.full(300, 0.1), np.full(300, 10.0))
    assert np.all(np.isfinite(y))
    assert y[-1, 0] == pytest.approx(0.1 - 10.0 / 1e6, abs=1e-9)
    a.free()


@pytest.mark.parametrize("name,value,code", [("footplate_inertia", 0.0, 3), ("servo_bandwidth", -1.0, 1),
                                             ("coupling_damping", -0.1, 5)])
def test_invalid_parameter_is_reported(fmu, name, value, code):
    a = Actuator(*fmu, **{name: value})
    with pytest.raises(FMICallException):
        a.fmu.exitInitializationMode()
    assert any(f"sys_initial_state failed (code {code})" in m for m in a.logs), a.logs
    a.set([PARAM[name]], [ACTUATOR_DEFAULTS[name]])  # fixable during initialization
    a.start()
    a.free()


def test_two_minute_record(fmu):
    """120,000 internal steps at 10 ms communication: PRALDS-like perturbations around slow
    position levels, ankle-like load torque; every output finite, command tracked."""
    rng = np.random.default_rng(11)
    h, n = 0.01, 12_000
    levels = np.repeat(rng.uniform(-0.4, 0.2, n // 1000), 1000)
    holds = rng.integers(25, 36, n)  # 250-350 ms holds of +-0.04 rad
    pert = np.repeat(rng.choice([-0.04, 0.04], n), holds)[:n]
    cmd = levels + pert
    a = make(fmu, initial_position=float(cmd[0]))
    out = np.empty((n, 3))
    pos = float(cmd[0])
    t0 = time.perf_counter()
    for k in range(n):
        load = 100.0 * pos + rng.normal(0, 0.5)  # elastic ankle torque (N m) plus noise
        a.set([CMD, LOAD], [float(cmd[k]), load])
        a.fmu.doStep(a.t, h)
        a.t += h
        out[k] = a.get([POS, VEL, ACC])
        pos = out[k, 0]
    elapsed = time.perf_counter() - t0
    assert np.all(np.isfinite(out))
    assert a.t == pytest.approx(120.0)
    # after each hold the position is within the static deflection of the command
    settled = np.abs(out[:, 0] - cmd) < 50.0 / ACTUATOR_DEFAULTS["servo_stiffness"] + 1e-4
    assert settled.mean() > 0.8
    assert np.abs(out[:, 0]).max() < 0.5
    a.free()
    print(f"2-minute record: {n * 10 / elapsed:,.0f} internal steps/s ({n / elapsed:,.0f} communication steps/s)")
