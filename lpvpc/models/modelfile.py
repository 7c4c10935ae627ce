"""Model files as untrusted input: the one check every command runs before building anything.

A model file is e-mailed between labs and edited by hand. Whatever reaches
:class:`lpvpc.models.model.LPVPCModel` (and from there numpy prediction, CasADi code generation,
the C compiler and the FMU) has first passed :func:`read_model_file` (the bytes: a regular
file, at most :data:`MAX_FILE_BYTES`, UTF-8 JSON, no duplicate keys, nesting at most
:data:`MAX_NESTING_DEPTH`) and :func:`check_model_dict` (the schema: types, shapes, finite
values, and limits that bound the work of export and prediction). Each refusal is a
:class:`~lpvpc.errors.ModelFileError` naming the field, its value and the limit by name.

The limits are generous for any identified ankle model (the default identification at
100 Hz has 7 lags, a delay of 4 samples, orders <= 5, state order 2, ~120 coefficients)
and keep what passes cheap: at the limits an FMU export takes seconds and prediction's
memory grows linearly with the record (see ``benchmarks/bench_fuzz_model.py``).

Extending the format: the fields known here are checked strictly; other top-level
sections are allowed (bounded by the size and nesting limits). A module that adds a
section registers its check in :data:`SECTION_CHECKS` (``name -> check(value, where,
problems, d)``, appending one-line problems) so that every command runs it.
"""

from __future__ import annotations

import json
import math
import os
import stat

import numpy as np

from .equations import DERIVATIVE_STENCILS
from ..errors import ModelFileError

#: The near-equivalent structures a model file may carry for its intervals' structural term
#: (closest in cross-validation error first).
MAX_STRUCTURES = 24
#: Quantities whose intervals count the shift between the model's own estimate and the search's
#: refit of its structure (``path``: the reflex's velocity path on the 1 kHz path, the reflex
#: structure the intrinsic estimate sees at the model rate;
#: lpvpc.identification.structural_uncertainty).
PATH_QUANTITIES = ("viscosity",)
#: Quantities whose intervals count the reflex-dynamics leak (``leak``: the IRF's shift when the
#: reflex dynamics are left free; lpvpc.identification.structural_uncertainty.reflex_leak_shift).
LEAK_QUANTITIES = ("stiffness",)

FORMAT = "lpvpc-model"
FORMAT_VERSION = 1
FORMAT_VERSION_EFFECTS = 2  # written (only) by extended models: older readers refuse them
FORMAT_VERSION_CURVATURE = 3  # written by models with the elastic curvature term (any effects)

# --------------------------------------------------------------------------- limits
MAX_FILE_BYTES = 8 * 1024 * 1024  #: bytes read from a model file (the default model is ~6 KB)
MAX_NESTING_DEPTH = 32  #: JSON nesting (a model needs 5)
MAX_FS = 100_000.0  # Hz: sampling rate
MAX_LAG = 100  # samples: |lag| of the two-sided intrinsic IRF (the causal IRF: MAX_LAG + 2, its default)
MAX_DELAY = 250  # samples: reflex delay (250 ms at 1 kHz; ankle reflexes: 40-120 ms)
MAX_BASIS_ORDER = 12  # order of every basis (scheduling, velocity, effects)
MAX_STATE_ORDER = 12  # order m of the reflex linear dynamics
MAX_COEFFICIENTS = 4_000  # identified coefficients in all arrays (each becomes an FMU parameter)
MAX_ABS_VALUE = 1e9  # magnitude of any coefficient and basis range bound (SI units)
MIN_BASIS_SPAN = 1e-10  # hi - lo of a basis range
MAX_SPECTRAL_RADIUS = 1.0  # reflex dynamics A: all eigenvalues strictly inside the unit circle
MAX_RELAXATION_S = 60.0  # s: a stress-relaxation averaging time (tissue relaxation: 0.1-10 s)
MAX_ITEMS = 1_000_000  # JSON values in the whole file

POSITION_UNITS = ("rad", "deg")
TORQUE_SIGNS = (1.0, -1.0)

_INT_SETTINGS = {"irf_lags": MAX_LAG, "causal_lags": MAX_LAG + 2, "intrinsic_order": MAX_BASIS_ORDER,
                 "reflex_order": MAX_BASIS_ORDER, "velocity_order": MAX_BASIS_ORDER,
                 "state_order": MAX_STATE_ORDER, "min_state_order": MAX_STATE_ORDER,
                 "max_state_order": MAX_STATE_ORDER, "horizon": 10 * MAX_LAG, "max_iter": 100_000}


# --------------------------------------------------------------------------- bytes
def _no_duplicate_keys(pairs):
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def read_model_file(path) -> dict:
    """The parsed JSON of a model file, refused unless it is a regular file of at most
    :data:`MAX_FILE_BYTES` bytes holding UTF-8 JSON without duplicate keys, nested at most
    :data:`MAX_NESTING_DEPTH` deep. The schema is :func:`check_model_dict`'s job.

    >>> import tempfile
    >>> from pathlib import Path
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = Path(tmp) / "model.json"
    ...     _ = path.write_text('{"format": "lpvpc-model", "format": "again"}')
    ...     read_model_file(path)
    Traceback (most recent call last):
    ...
    lpvpc.errors.ModelFileError: ...duplicate key...
    """
    name = str(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise ModelFileError(f"{name}: model file not found") from None
    except OSError as exc:
        raise ModelFileError(f"{name}: cannot read the model file ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise ModelFileError(f"{name}: not a regular file (a model file is a JSON file)")
    if st.st_size > MAX_FILE_BYTES:
        raise ModelFileError(f"{name}: {st.st_size} bytes exceeds MAX_FILE_BYTES = {MAX_FILE_BYTES}")
    try:
        with open(path, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # replaced since the stat
                raise ModelFileError(f"{name}: not a regular file (a model file is a JSON file)")
            raw = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ModelFileError(f"{name}: cannot read the model file ({exc.strerror or exc})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ModelFileError(f"{name}: more than MAX_FILE_BYTES = {MAX_FILE_BYTES} bytes")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ModelFileError(f"{name}: corrupt model file (not UTF-8 text: byte {exc.start})") from None
    try:
        d = json.loads(text, object_pairs_hook=_no_duplicate_keys)
    except RecursionError:
        raise ModelFileError(f"{name}: JSON nested deeper than MAX_NESTING_DEPTH = {MAX_NESTING_DEPTH}") from None
    except MemoryError:
        raise ModelFileError(f"{name}: corrupt model file (out of memory while parsing)") from None
    except ValueError as exc:  # JSONDecodeError, duplicate keys, integers too long to convert
        raise ModelFileError(f"{name}: corrupt model file ({_short(exc)})") from None
    _check_tree(d, name)
    return d


def _short(exc, n=160) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _check_tree(d, name):
    """Nesting depth and number of values, without recursion."""
    stack, count = [(d, 1)], 0
    while stack:
        value, depth = stack.pop()
        count += 1
        if depth > MAX_NESTING_DEPTH:
            raise ModelFileError(f"{name}: JSON nested deeper than MAX_NESTING_DEPTH = {MAX_NESTING_DEPTH}")
        if count > MAX_ITEMS:
            raise ModelFileError(f"{name}: more than MAX_ITEMS = {MAX_ITEMS} JSON values")
        if isinstance(value, dict):
            stack.extend((v, depth + 1) for v in value.values())
        elif isinstance(value, list):
            stack.extend((v, depth + 1) for v in value)


# --------------------------------------------------------------------------- schema
class _Refused(Exception):
    """A problem after which the rest of a section cannot be checked."""


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _isfinite(x) -> bool:
    try:
        return math.isfinite(x)
    except OverflowError:  # an integer beyond the float range
        return False


def _is_rate(x) -> bool:
    """A sampling rate a model file may carry: a finite number in (0, MAX_FS] Hz."""
    return _is_number(x) and _isfinite(x) and 0 < x <= MAX_FS


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _show(x, n=40) -> str:
    text = repr(x)
    return text if len(text) <= n else text[: n - 3] + "..."


def _number(x, where, problems, *, lo=-MAX_ABS_VALUE, hi=MAX_ABS_VALUE, limit="MAX_ABS_VALUE"):
    if not _is_number(x):
        problems.append(f"{where} must be a number, got {_show(x)}")
        return None
    if not _isfinite(x):
        problems.append(f"{where} = {x!r} is not finite")
        return None
    if not lo <= x <= hi:
        problems.append(f"{where} = {_show(x)} outside [{lo:g}, {hi:g}] ({limit})")
        return None
    return float(x)


def _integer(x, where, problems, lo, hi, limit):
    if not _is_int(x):
        problems.append(f"{where} must be an integer, got {_show(x)}")
        return None
    if not lo <= x <= hi:
        problems.append(f"{where} = {_show(x)} outside [{lo}, {hi}] ({limit})")
        return None
    return x


def _dict(x, where, problems, required=False):
    if x is None and not required:
        return {}
    if not isinstance(x, dict):
        problems.append(f"{where} must be an object, got {type(x).__name__}")
        raise _Refused
    return x


def _array(x, where, problems, ndim, budget) -> np.ndarray:
    """A rectangular list (ndim 1) or list of lists (ndim 2) of finite numbers of
    magnitude <= MAX_ABS_VALUE, as a float array."""
    rows = x if ndim == 2 else [x]
    if not isinstance(x, list) or (ndim == 2 and not all(isinstance(r, list) for r in rows)):
        problems.append(f"{where} must be a {'list of lists' if ndim == 2 else 'list'} of numbers")
        raise _Refused
    size = sum(len(r) for r in rows)
    budget[0] += size
    if budget[0] > MAX_COEFFICIENTS:
        problems.append(f"more than MAX_COEFFICIENTS = {MAX_COEFFICIENTS} coefficients (at {where})")
        raise _Refused
    if ndim == 2 and len({len(r) for r in rows}) > 1:
        problems.append(f"{where} has rows of different lengths")
        raise _Refused
    for i, r in enumerate(rows):
        for j, v in enumerate(r):
            if not _is_number(v) or (isinstance(v, int) and abs(v) > MAX_ABS_VALUE):
                problems.append(f"{where}{f'[{i}]' if ndim == 2 else ''}[{j}] must be a number of magnitude at "
                                f"most MAX_ABS_VALUE = {MAX_ABS_VALUE:g}, got {_show(v)}")
                raise _Refused
    a = np.array(x, dtype=float)
    if ndim == 2 and a.ndim == 1:  # []
        a = a.reshape(0, 0)
    bad = ~np.isfinite(a)
    if bad.any():
        problems.append(f"{where}: {int(bad.sum())} non-finite values")
        raise _Refused
    big = np.abs(a) > MAX_ABS_VALUE
    if big.any():
        problems.append(f"{where}: {int(big.sum())} values of magnitude above MAX_ABS_VALUE = {MAX_ABS_VALUE:g}")
        raise _Refused
    return a


def _shape(a, expected, where, problems):
    if a.shape != expected:
        problems.append(f"{where} has shape {a.shape}, expected {expected}")
        raise _Refused


def _lags(x, where, problems, lo, hi=MAX_LAG):
    if not isinstance(x, list) or not x:
        problems.append(f"{where} must be a non-empty list of integers")
        raise _Refused
    if len(x) > 2 * MAX_LAG + 1:
        problems.append(f"{where}: {len(x)} lags exceed 2 MAX_LAG + 1 = {2 * MAX_LAG + 1}")
        raise _Refused
    out = []
    for i, v in enumerate(x):
        if _integer(v, f"{where}[{i}]", problems, lo, hi, "MAX_LAG" if hi == MAX_LAG else "MAX_LAG + 2") is None:
            raise _Refused
        out.append(v)
    if len(set(out)) != len(out):
        dup = sorted({v for v in out if out.count(v) > 1})
        problems.append(f"{where}: duplicate lags {dup}")
        raise _Refused
    return out


def _basis(x, where, problems):
    from .basis import EXTRAPOLATIONS, FAMILIES

    b = _dict(x, where, problems, required=True)
    unknown = sorted(set(b) - {"family", "order", "lo", "hi", "extrapolation"})
    if unknown:
        problems.append(f"{where}: unknown field(s) {', '.join(unknown)}")
        raise _Refused
    family, extrap = b.get("family"), b.get("extrapolation", "clip")
    if family not in FAMILIES:
        problems.append(f"{where}.family must be one of {', '.join(FAMILIES)}, got {_show(family)}")
        raise _Refused
    if extrap not in EXTRAPOLATIONS:
        problems.append(f"{where}.extrapolation must be one of {', '.join(EXTRAPOLATIONS)}, got {_show(extrap)}")
        raise _Refused
    if family == "gaussian" and extrap != "clip":
        problems.append(f"{where}: a gaussian basis supports only extrapolation 'clip'")
        raise _Refused
    order = _integer(b.get("order"), f"{where}.order", problems, 0, MAX_BASIS_ORDER, "MAX_BASIS_ORDER")
    lo, hi = _number(b.get("lo"), f"{where}.lo", problems), _number(b.get("hi"), f"{where}.hi", problems)
    if order is None or lo is None or hi is None:
        raise _Refused
    if not hi - lo >= MIN_BASIS_SPAN:
        problems.append(f"{where}: range [{lo!r}, {hi!r}] narrower than MIN_BASIS_SPAN = {MIN_BASIS_SPAN:g}")
        raise _Refused
    return order + 1


def _check_intrinsic(x, where, problems, d, budget):
    s = _dict(x, where, problems, required=True)
    lags = _lags(s.get("lags"), f"{where}.lags", problems, -MAX_LAG)
    causal = _lags(s.get("causal_lags"), f"{where}.causal_lags", problems, 0, MAX_LAG + 2)
    n_i = _basis(s.get("basis"), f"{where}.basis", problems)
    _shape(_array(s.get("H"), f"{where}.H", problems, 2, budget), (len(lags), n_i), f"{where}.H", problems)
    _shape(_array(s.get("H_causal"), f"{where}.H_causal", problems, 2, budget), (len(causal) + 2, n_i),
           f"{where}.H_causal", problems)
    if s.get("curvature") is not None:
        _shape(_array(s.get("curvature"), f"{where}.curvature", problems, 1, budget), (n_i,), f"{where}.curvature",
               problems)
    if s.get("derivatives", "central3") not in DERIVATIVE_STENCILS:  # absent in older files: central3
        problems.append(f"{where}.derivatives = {_show(s.get('derivatives'))} is not one of {DERIVATIVE_STENCILS}")


def _check_reflex(x, where, problems, d, budget):
    s = _dict(x, where, problems, required=True)
    if _integer(s.get("delay"), f"{where}.delay", problems, 1, MAX_DELAY, "MAX_DELAY (samples)") is None:
        raise _Refused
    n_v = _basis(s.get("velocity_basis"), f"{where}.velocity_basis", problems)
    n_r = _basis(s.get("rho_basis"), f"{where}.rho_basis", problems)
    _shape(_array(s.get("Omega"), f"{where}.Omega", problems, 2, budget), (n_v, n_r), f"{where}.Omega", problems)
    A = _array(s.get("A"), f"{where}.A", problems, 2, budget)
    m = A.shape[0]
    if not 1 <= m <= MAX_STATE_ORDER:
        problems.append(f"{where}.A: state order {m} outside [1, {MAX_STATE_ORDER}] (MAX_STATE_ORDER)")
        raise _Refused
    _shape(A, (m, m), f"{where}.A", problems)
    _shape(_array(s.get("B"), f"{where}.B", problems, 1, budget), (m,), f"{where}.B", problems)
    _shape(_array(s.get("C"), f"{where}.C", problems, 1, budget), (m,), f"{where}.C", problems)
    if _number(s.get("D"), f"{where}.D", problems) is None:
        raise _Refused
    if s.get("high_rate") is not None:  # optional: the nonlinearity identified at the file's rate (lpvpc.models.model)
        _check_high_rate(s["high_rate"], f"{where}.high_rate", problems, d, budget, n_r)
    radius = float(np.max(np.abs(np.linalg.eigvals(A))))
    if not radius < MAX_SPECTRAL_RADIUS:
        problems.append(f"{where}.A: unstable reflex dynamics, spectral radius {radius:.6g} "
                        f"(must be below MAX_SPECTRAL_RADIUS = {MAX_SPECTRAL_RADIUS:g})")
        raise _Refused


def _check_high_rate(x, where, problems, d, budget, n_r):
    h = _dict(x, where, problems, required=True)
    fs, model_fs = _number(h.get("fs"), f"{where}.fs", problems, lo=0.0, hi=MAX_FS, limit="MAX_FS"), d.get("fs")
    if fs is not None and _is_number(model_fs) and _isfinite(model_fs) and model_fs > 0:
        q = fs / model_fs
        if not (q > 1.5 and abs(q - round(q)) < 1e-6 * q):
            problems.append(f"{where}.fs = {fs!r} Hz is not an integer multiple (> 1) of the model's fs {model_fs!r} Hz")
        else:
            _integer(h.get("delay"), f"{where}.delay", problems, 1, MAX_DELAY * round(q), "MAX_DELAY (model samples)")
    n_v = _basis(h.get("velocity_basis"), f"{where}.velocity_basis", problems)
    _shape(_array(h.get("Omega"), f"{where}.Omega", problems, 2, budget), (n_v, n_r), f"{where}.Omega", problems)


def _check_conventions(x, where, problems, d, budget):
    c = _dict(x, where, problems)
    if "torque_sign" in c and not (_is_number(c["torque_sign"]) and c["torque_sign"] in TORQUE_SIGNS):
        problems.append(f"{where}.torque_sign must be 1 or -1, got {_show(c['torque_sign'])}")
    if "position_unit" in c and c["position_unit"] not in POSITION_UNITS:
        problems.append(f"{where}.position_unit must be one of {', '.join(POSITION_UNITS)}, "
                        f"got {_show(c['position_unit'])}")
    if "channel_skew_s" in c:  # s, the recording's torque lag undone at loading (lpvpc.identification.channel_skew)
        _number(c["channel_skew_s"], f"{where}.channel_skew_s", problems, lo=-0.02, hi=0.02, limit="+-20 ms")


def _check_settings(x, where, problems, d, budget):
    s = _dict(x, where, problems)
    for key, top in _INT_SETTINGS.items():
        v = s.get(key)
        if v is not None and not (_is_number(v) and _isfinite(v) and 0 <= v <= top):
            problems.append(f"{where}.{key} = {_show(v)} outside [0, {top}]")
    if s.get("reflex_delay") is not None:  # seconds
        _number(s["reflex_delay"], f"{where}.reflex_delay", problems, lo=0.0, hi=MAX_DELAY / d["fs"],
                limit="MAX_DELAY samples")
    if "effects" in s and not isinstance(s["effects"], (list, tuple)):
        problems.append(f"{where}.effects must be a list of effect names")
    if "allow_effects" in s and not (isinstance(s["allow_effects"], (list, tuple))
                                     and all(isinstance(n, str) for n in s["allow_effects"])):
        problems.append(f"{where}.allow_effects must be a list of effect names")


def _check_fit(x, where, problems, d, budget):
    f = _dict(x, where, problems)
    if "stiffness" in f:
        _check_stiffness(f["stiffness"], f"{where}.stiffness", problems, d)
    if "velocity_p99" in f:
        _number(f["velocity_p99"], f"{where}.velocity_p99", problems)
    if "data_density" in f:  # figures only; its own budget (not FMU parameters)
        dd = _dict(f["data_density"], f"{where}.data_density", problems, required=True)
        e_r = _array(dd.get("scheduling_edges"), f"{where}.data_density.scheduling_edges", problems, 1, [0])
        e_v = _array(dd.get("velocity_edges"), f"{where}.data_density.velocity_edges", problems, 1, [0])
        counts = _array(dd.get("counts"), f"{where}.data_density.counts", problems, 2, [0])
        for e, name in ((e_r, "scheduling_edges"), (e_v, "velocity_edges")):
            if len(e) < 2 or np.any(np.diff(e) <= 0):
                problems.append(f"{where}.data_density.{name} must be at least 2 increasing values")
                raise _Refused
        _shape(counts, (len(e_r) - 1, len(e_v) - 1), f"{where}.data_density.counts", problems)
        if np.any(counts < 0):
            problems.append(f"{where}.data_density.counts must be non-negative")


def _check_stiffness(x, where, problems, d):
    """``fit.stiffness`` of a model with stress relaxation (lpvpc.models.effects.relaxation_stiffness_entry):
    the short-range and relaxed stiffness, each labelled, in N m/rad, at the same positions."""
    e = _dict(x, where, problems, required=True)
    rho = _array(e.get("scheduling"), f"{where}.scheduling", problems, 1, [0])
    for key in ("short_range", "relaxed"):
        k = _dict(e.get(key), f"{where}.{key}", problems, required=True)
        if not isinstance(k.get("label"), str) or not k["label"]:
            problems.append(f"{where}.{key}.label must be a non-empty text")
        if k.get("unit") != "N m/rad":
            problems.append(f"{where}.{key}.unit must be 'N m/rad', got {_show(k.get('unit'))}")
        values = _array(k.get("values"), f"{where}.{key}.values", problems, 1, [0])
        _shape(values, rho.shape, f"{where}.{key}.values", problems)
        if "determined" in k and not (isinstance(k["determined"], list) and len(k["determined"]) == len(rho)
                                      and all(isinstance(b, bool) for b in k["determined"])):
            problems.append(f"{where}.{key}.determined must be a list of {len(rho)} true/false values")


MAX_UNCERTAINTY_PARAMETERS = 1_000  # size p of the stored p x p covariance


def _check_uncertainty(x, where, problems, d, budget):
    """The confidence-interval section (:mod:`lpvpc.models.uncertainty`): parameter counts that
    match the model, a symmetric p x p covariance with a non-negative diagonal, the
    truncated IRF and the VAF interval. Its numbers are not FMU parameters: own budget."""
    u = _dict(x, where, problems)
    if not u:
        return
    par = _dict(u.get("parameters"), f"{where}.parameters", problems, required=True)
    n = {}
    for key in ("theta_i", "extension", "omega", "bd", "den"):  # extension: an extended model's effects
        v = par.get(key, 0 if key in ("den", "extension") else None)
        n[key] = _integer(v, f"{where}.parameters.{key}", problems, 0, MAX_UNCERTAINTY_PARAMETERS,
                          "MAX_UNCERTAINTY_PARAMETERS")
        if n[key] is None:
            raise _Refused
    intr, refl = d["intrinsic"], d["reflex"]
    m = len(refl["B"])
    om = (refl.get("high_rate") or refl)["Omega"]  # the identified nonlinearity's (lpvpc.models.model notes)
    expect = {"theta_i": len(intr["H"]) * len(intr["H"][0]), "omega": len(om) * len(om[0]),
              "bd": m + 1}
    for key, val in expect.items():
        if n[key] != val:
            problems.append(f"{where}.parameters.{key} = {n[key]} does not match the model ({val})")
    if n["den"] not in (0, m):
        problems.append(f"{where}.parameters.den = {n['den']} must be 0 or the state order {m}")
    if n["extension"] and not d.get("effects"):
        problems.append(f"{where}.parameters.extension = {n['extension']} but the model has no effects")
    if problems:
        raise _Refused
    p = sum(n.values())
    if p > MAX_UNCERTAINTY_PARAMETERS:
        problems.append(f"{where}: {p} parameters exceed MAX_UNCERTAINTY_PARAMETERS = {MAX_UNCERTAINTY_PARAMETERS}")
        raise _Refused
    cov = _array(u.get("covariance"), f"{where}.covariance", problems, 2, [-p * p])
    _shape(cov, (p, p), f"{where}.covariance", problems)
    if np.any(np.diag(cov) < 0) or not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(cov).max())):
        problems.append(f"{where}.covariance must be symmetric with a non-negative diagonal")
    if "truncation" in u:
        t = _dict(u["truncation"], f"{where}.truncation", problems, required=True)
        lags = _lags(t.get("lags"), f"{where}.truncation.lags", problems, -MAX_LAG)
        _shape(_array(t.get("H"), f"{where}.truncation.H", problems, 2, [0]), (len(lags), len(intr["H"][0])),
               f"{where}.truncation.H", problems)
    if "richer_basis" in u:
        r = _dict(u["richer_basis"], f"{where}.richer_basis", problems, required=True)
        n_b = _basis(r.get("basis"), f"{where}.richer_basis.basis", problems)
        _shape(_array(r.get("H"), f"{where}.richer_basis.H", problems, 2, [0]), (len(intr["H"]), n_b),
               f"{where}.richer_basis.H", problems)
    if "curvature_reflex" in u:
        c = _dict(u["curvature_reflex"], f"{where}.curvature_reflex", problems, required=True)
        for key, size in (("omega", n["omega"]), ("bd", m + 1)):
            _shape(_array(c.get(key), f"{where}.curvature_reflex.{key}", problems, 1, [0]), (size,),
                   f"{where}.curvature_reflex.{key}", problems)
    if "knee_rounding" in u:  # lpvpc.models.reflex_uncertainty.knee_rounding: one curve over thresholds
        kr = _dict(u["knee_rounding"], f"{where}.knee_rounding", problems, required=True)
        t = _array(kr.get("threshold"), f"{where}.knee_rounding.threshold", problems, 1, [0])
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            problems.append(f"{where}.knee_rounding.threshold must be at least 2 increasing values")
        for key in ("gain_factor", "fitted_threshold"):
            _shape(_array(kr.get(key), f"{where}.knee_rounding.{key}", problems, 1, [0]), (len(t),),
                   f"{where}.knee_rounding.{key}", problems)
    if "reflex_determined" in u:  # lpvpc.models.reflex_uncertainty.reflex_determination: derived, rewritten on save
        r = _dict(u["reflex_determined"], f"{where}.reflex_determined", problems, required=True)
        if r:
            rho = _array(r.get("rho"), f"{where}.reflex_determined.rho", problems, 1, [0])
            for key in ("gain", "threshold"):
                flags = r.get(key)
                if not isinstance(flags, list) or len(flags) != len(rho) or not all(isinstance(b, bool) for b in flags):
                    problems.append(f"{where}.reflex_determined.{key} must be a list of {len(rho)} true/false values")
    if "structural" in u:
        _check_structural(u["structural"], f"{where}.structural", problems, budget)
    v = _dict(u.get("vaf"), f"{where}.vaf", problems, required=True)
    for key in ("estimate", "lower", "upper"):
        _number(v.get(key), f"{where}.vaf.{key}", problems)
    _number(v.get("level"), f"{where}.vaf.level", problems, lo=0.0, hi=1.0, limit="a probability")
    _number(u.get("block_length_s"), f"{where}.block_length_s", problems, lo=0.0)


def _check_structural(x, where, problems, budget):
    """The structural term of the intrinsic intervals (:mod:`lpvpc.identification.structural_uncertainty`):
    one IRF-weight shift per near-equivalent structure, on one basis and lag set."""

    st = _dict(x, where, problems, required=True)
    n_b = _basis(st.get("basis"), f"{where}.basis", problems)
    lags = _lags(st.get("lags"), f"{where}.lags", problems, -MAX_LAG)
    shifts = st.get("shifts")
    if not isinstance(shifts, list) or len(shifts) > MAX_STRUCTURES:
        problems.append(f"{where}.shifts must be a list of at most MAX_STRUCTURES = {MAX_STRUCTURES} IRF shifts")
        raise _Refused
    for i, h in enumerate(shifts):
        _shape(_array(h, f"{where}.shifts[{i}]", problems, 2, budget), (len(lags), n_b), f"{where}.shifts[{i}]",
               problems)
    if not isinstance(st.get("structures"), list) or len(st["structures"]) != len(shifts):
        problems.append(f"{where}.structures must list the {len(shifts)} structures of the shifts")
    if "path" in st:
        _check_path_shift(st["path"], f"{where}.path", problems, budget, (len(lags), n_b))
    if "leak" in st:
        _check_path_shift(st["leak"], f"{where}.leak", problems, budget, (len(lags), n_b), LEAK_QUANTITIES)
    if "reflex" in st:
        _check_reflex_structures(st["reflex"], f"{where}.reflex", problems, budget)


def _check_path_shift(x, where, problems, budget, shape, allowed=PATH_QUANTITIES):
    """``structural.path`` (the IRF shift of the other reflex velocity path) or ``structural.leak``
    (the IRF shift with the reflex dynamics free), on the term's lags and basis; ``allowed``: the
    quantities it may name."""

    p = _dict(x, where, problems, required=True)
    q = p.get("quantities")
    if not isinstance(q, list) or not all(isinstance(k, str) for k in q) or not set(q) <= set(allowed):
        problems.append(f"{where}.quantities must be a list drawn from {', '.join(allowed)}")
    _shape(_array(p.get("shift"), f"{where}.shift", problems, 2, budget), shape, f"{where}.shift", problems)


def _check_reflex_structures(x, where, problems, budget):
    """``structural.reflex``: the reflex gain's near-equivalent structures, each a refit of the
    nonlinearity (n_v x n_r coefficients on its velocity basis and the term's scheduling basis)."""

    r = _dict(x, where, problems, required=True)
    n_r = _basis(r.get("rho_basis"), f"{where}.rho_basis", problems)
    structures = r.get("structures")
    if not isinstance(structures, list) or len(structures) > MAX_STRUCTURES:
        problems.append(f"{where}.structures must be a list of at most MAX_STRUCTURES = {MAX_STRUCTURES} refits")
        raise _Refused
    for w, e in [(f"{where}.reference", r.get("reference"))] + [(f"{where}.structures[{i}]", e)
                                                                  for i, e in enumerate(structures)]:
        e = _dict(e, w, problems, required=True)
        n_v = _basis(e.get("velocity_basis"), f"{w}.velocity_basis", problems)
        _shape(_array(e.get("coefficients"), f"{w}.coefficients", problems, 2, budget), (n_v, n_r),
               f"{w}.coefficients", problems)


def _check_effects(x, where, problems, d, budget):
    from .effects import CATALOG

    if x is None:
        return
    if not isinstance(x, list):
        problems.append(f"{where} must be a list")
        raise _Refused
    if len(x) > len(CATALOG):
        problems.append(f"{where}: {len(x)} effects, more than the catalog's {len(CATALOG)}")
        raise _Refused
    m = len(d["reflex"]["A"])
    names = []
    for k, e in enumerate(x):
        w = f"{where}[{k}]"
        e = _dict(e, w, problems, required=True)
        name = e.get("name")
        if not isinstance(name, str) or name not in CATALOG:
            problems.append(f"{w}.name must be one of {', '.join(CATALOG)}, got {_show(name)}")
            raise _Refused
        if name in names:
            problems.append(f"{where}: effect {name} listed twice")
            raise _Refused
        names.append(name)
        eff = CATALOG[name]
        w = f"{where}[{name}]"
        sizes = {key: _basis(e[key], f"{w}.{key}", problems) for key in ("basis", "channel_basis") if key in e}
        need = (("H", "H_causal") if eff.channels is not None else ()) + (
            ("Theta", "basis") if eff.features is not None else ())
        missing = [key for key in need if key not in e]
        if missing:
            problems.append(f"{w}: missing {', '.join(missing)}")
            raise _Refused
        arrays = {key: _array(e[key], f"{w}.{key}", problems, 2, budget) for key in ("H", "H_causal", "Theta")
                  if key in e}
        opts = _dict(e.get("options"), f"{w}.options", problems)
        for key, v in opts.items():
            ok = isinstance(v, (bool, str)) or (_is_number(v) and _isfinite(v)) or (
                isinstance(v, list) and len(v) <= MAX_STATE_ORDER
                and all(_is_number(u) and _isfinite(u) for u in v))
            if not ok:
                problems.append(f"{w}.options.{key}: not a finite number, flag, name or short list of numbers")
                raise _Refused
        if "relaxation" in eff.derived and "relaxation_times_s" in opts:  # absent in older files: RELAXATION_TIMES
            times = opts["relaxation_times_s"]
            if not (isinstance(times, list) and times and all(_is_number(t) and 0.0 < t <= MAX_RELAXATION_S
                                                              for t in times)):
                problems.append(f"{w}.options.relaxation_times_s = {_show(times)}: needs a list of averaging times "
                                f"in s, each in (0, {MAX_RELAXATION_S:g}]")
                raise _Refused
        if eff.uses_reflex:
            if not (opts.get("m") == m and _is_int(opts.get("m")) and isinstance(opts.get("kappa"), list)
                    and len(opts["kappa"]) == m and _is_number(opts.get("c_kappa"))):
                problems.append(f"{w}.options: needs m = {m} (the reflex state order), kappa ({m} numbers) and c_kappa")
                raise _Refused
        if "reflex_delays" in eff.derived:  # the reflex re-run at delays d + j: causal, within MAX_DELAY
            d0, steps = d["reflex"].get("delay"), opts.get("steps")
            if not (isinstance(steps, list) and steps and all(_is_int(j) and j != 0 and 1 <= d0 + j <= MAX_DELAY
                                                              for j in steps) and len(set(steps)) == len(steps)):
                problems.append(f"{w}.options.steps: needs distinct nonzero delay steps j (samples) with "
                                f"1 <= delay + j <= MAX_DELAY ({MAX_DELAY})")
                raise _Refused
        intr = d["intrinsic"]
        if eff.channels is not None:
            n_c = sizes.get("channel_basis", intr["basis"]["order"] + 1)
            width = _n_channels(eff) * n_c
            _shape(arrays["H"], (len(intr["lags"]), width), f"{w}.H", problems)
            _shape(arrays["H_causal"], (len(intr["causal_lags"]) + 2, width), f"{w}.H_causal", problems)
        if eff.features is not None:
            n_f = len(eff.feature_names(opts)) if eff.feature_names is not None else arrays["Theta"].shape[0]
            _shape(arrays["Theta"], (n_f, sizes["basis"] - (not eff.feature_constant)), f"{w}.Theta", problems)


def _n_channels(effect) -> int:
    """How many channels schedule an effect's IRF (evaluated on a one-sample context)."""
    from .basis import NUMPY
    from .effects import SIGNALS, Context

    one = np.ones((1, 1))
    ctx = Context(rho=one, velocity=one, direction=one, **{s: one for s in SIGNALS})
    return len(effect.channels(ctx, NUMPY))


#: Checks of the top-level sections, in order: name -> check(value, where, problems, d,
#: budget). ``budget`` is a one-element list counting coefficients against
#: MAX_COEFFICIENTS (pass it to ``_array``). Sections not listed are allowed.
SECTION_CHECKS = {
    "intrinsic": _check_intrinsic,
    "reflex": _check_reflex,
    "effects": _check_effects,
    "conventions": _check_conventions,
    "settings": _check_settings,
    "fit": _check_fit,
    "uncertainty": _check_uncertainty,
}
REQUIRED_SECTIONS = ("intrinsic", "reflex")
DICT_SECTIONS = ("settings", "provenance", "conventions", "fit", "units", "identified_ranges", "uncertainty")


def check_model_dict(d, source: str = "model") -> None:
    """Refuse (:class:`~lpvpc.errors.ModelFileError`, one line naming each problem and
    its limit) a parsed model file that lpvpc must not build anything from.

    A saved model passes; the same with a non-finite sampling rate is refused, naming it:

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> d = identify(pair_trials(sim.pt, sim.ut)).to_dict()
    >>> check_model_dict(d)
    >>> check_model_dict({**d, "fs": float("inf")})
    Traceback (most recent call last):
    ...
    lpvpc.errors.ModelFileError: model: corrupt model file: fs = inf Hz outside (0, ...] (MAX_FS)
    """
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise ModelFileError(f"{source}: not an lpvpc model file (missing 'format': '{FORMAT}')")
    version = d.get("format_version")
    if not _is_int(version) or version not in (FORMAT_VERSION, FORMAT_VERSION_EFFECTS, FORMAT_VERSION_CURVATURE):
        raise ModelFileError(f"{source}: unsupported model format_version {_show(version)} "
                             f"(expected {FORMAT_VERSION}, {FORMAT_VERSION_EFFECTS} or {FORMAT_VERSION_CURVATURE})")
    problems = []
    fs = d.get("fs")
    if not _is_number(fs):
        problems.append(f"fs must be a number (Hz), got {_show(fs)}")
    elif not _is_rate(fs):
        problems.append(f"fs = {fs!r} Hz outside (0, {MAX_FS:g}] (MAX_FS)")
    for key in REQUIRED_SECTIONS:
        if key not in d:
            problems.append(f"missing section {key!r}")
    for key in DICT_SECTIONS:
        if key in d and not isinstance(d[key], dict):
            problems.append(f"{key} must be an object, got {type(d[key]).__name__}")
    budget = [0]
    if not problems:
        for key, check in SECTION_CHECKS.items():
            if key in d:
                try:
                    check(d[key], key, problems, d, budget)
                except _Refused:
                    pass
            if problems and key in REQUIRED_SECTIONS:
                break  # the rest refers to these sections
    if problems:
        raise ModelFileError(f"{source}: corrupt model file: " + "; ".join(problems[:4])
                             + (f"; and {len(problems) - 4} more" if len(problems) > 4 else ""))


def check_whole_joint_dict(d: dict, source: str = "whole-joint model") -> None:
    """The whole-joint file's own fields (its embedded model goes through
    :func:`check_model_dict`): the quasi-static curve (a basis and its coefficients) and
    the low-pass cutoff, a number in (0, fs/2) Hz.

    >>> check_whole_joint_dict({"quasi_static": {"basis": {"family": "chebyshev", "order": 1, "lo": -0.4,
    ...                         "hi": 0.2}, "coefficients": [1.0, 2.0]}, "cutoff": 80.0, "model": {"fs": 100.0}})
    Traceback (most recent call last):
    ...
    lpvpc.errors.ModelFileError: whole-joint model: corrupt whole-joint model file: cutoff = 80.0 ... (fs/2)
    """
    problems = []
    try:
        qs = _dict(d.get("quasi_static"), "quasi_static", problems, required=True)
        n = _basis(qs.get("basis"), "quasi_static.basis", problems)
        _shape(_array(qs.get("coefficients"), "quasi_static.coefficients", problems, 1, [0]), (n,),
               "quasi_static.coefficients", problems)
        fs = d.get("model", {}).get("fs") if isinstance(d.get("model"), dict) else None
        nyquist = fs / 2 if _is_rate(fs) else MAX_FS / 2  # the embedded model is checked after this
        cutoff = _number(d.get("cutoff"), "cutoff", problems, lo=0.0, hi=nyquist, limit="fs/2")
        if cutoff is not None and not 0 < cutoff < nyquist:
            problems.append(f"cutoff = {cutoff!r} Hz outside (0, {nyquist:g}) (fs/2)")
    except _Refused:
        pass
    if problems:
        raise ModelFileError(f"{source}: corrupt whole-joint model file: " + "; ".join(problems[:4]))
