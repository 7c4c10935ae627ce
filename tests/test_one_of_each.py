"""The shared pieces the exports, the structure search, the diagnosis and the data doors
call: one CasADi-to-FMU conversion and build path, one cross-validation engine, one
sampling-rate check."""

import shutil

import numpy as np
import pytest

from lpvpc.export import exporter as ex
from lpvpc.identification.crossval import fold_fits, held_out_sse, solve_normal
from lpvpc.diagnosis.diagnose import diagnose
from lpvpc.errors import DataError
from lpvpc.io.identification_data import PerturbationData
from lpvpc.io.trial import check_model_rate


def _gain_step(parametric=True):
    """y = p u + x, x_next = u: a one-sample memory and a gain (params p)."""
    import casadi as ca

    x, u, p = ca.SX.sym("state"), ca.SX.sym("u"), ca.SX.sym("params")
    ins, names = ([x, u, p], ["state", "u", "params"]) if parametric else ([x, u], ["state", "u"])
    return ca.Function("gain", ins, [u, (p if parametric else 2.0) * u + x], names, ["next_state", "y"])


def test_the_conversion_refuses_a_step_without_params():
    pytest.importorskip("casadi")
    from lpvpc.errors import ExportError

    with pytest.raises(ExportError, match="not parametric"):
        ex.step_system_functions(_gain_step(parametric=False))


@pytest.mark.parametrize("fmi_type", ["cs", "me"])
def test_build_step_fmu_runs_the_step_it_was_given(tmp_path, fmi_type):
    """Any parametric step becomes an FMU through the one build path (a Model Exchange one
    suffixed _me); fmpy runs it and it answers as the step does."""
    pytest.importorskip("casadi")
    if shutil.which("gcc") is None and shutil.which("cc") is None:
        pytest.skip("no C compiler")
    from fmpy import read_model_description, simulate_fmu

    from lpvpc.export.fmu_build import FmuVariable

    path = ex.build_step_fmu(
        tmp_path / "gain.fmu", _gain_step(), model_identifier="gain", fmi_type=fmi_type, step_size=0.01,
        outputs=[FmuVariable("y", "output", "1", "p u + previous u", dependencies=["u"])],
        inputs=[FmuVariable("u", "input", "1", "input", 0.0)],
        parameters=[FmuVariable("p", "parameter", "1", "gain", 0.5)], fmi_version=2, description="test gain")
    md = read_model_description(str(path))
    ident = (md.modelExchange if fmi_type == "me" else md.coSimulation).modelIdentifier
    assert ident == ("gain_me" if fmi_type == "me" else "gain")
    u = np.array([1.0, 3.0, -2.0, 4.0, 0.0, 0.0])
    t = 0.01 * np.arange(len(u))
    kw = dict(fmi_type="ModelExchange", output_interval=0.01) if fmi_type == "me" else dict(step_size=0.01)
    res = simulate_fmu(str(path), input=np.rec.fromarrays([t, u], names=["time", "u"]), output=["y"],
                       stop_time=t[-1], **kw)
    if fmi_type == "me":  # each event time twice: keep the last
        res = res[np.r_[res["time"][1:] != res["time"][:-1], True]]
    y = np.interp(t, res["time"], res["y"])
    if fmi_type == "me":  # at t_k: sample k, y = p u(k) + u(k - 1)
        expected = 0.5 * u + np.r_[0.0, u[:-1]]
    else:  # simulate_fmu reads after the step that took u(k - 1), its state already u(k - 1)
        expected = np.r_[0.5 * u[0], 1.5 * u[:-1]]
    assert np.allclose(y, expected, atol=1e-12), (y, expected)


def test_fold_fits_equal_explicit_least_squares_on_the_other_folds():
    """Both ridge references, without a ridge, give the least-squares fit on the other folds,
    and held_out_sse the held-out fold's squared error."""
    rng = np.random.default_rng(0)
    X = rng.standard_normal((300, 4)) * [1.0, 1e2, 1e-2, 3.0]
    y = X @ [1.0, -0.02, 40.0, 0.5] + 0.1 * rng.standard_normal(300)
    folds = np.repeat(np.arange(3), 100)
    G = np.stack([X[folds == f].T @ X[folds == f] for f in range(3)])
    b = np.stack([X[folds == f].T @ y[folds == f] for f in range(3)])
    yy = np.array([y[folds == f] @ y[folds == f] for f in range(3)])
    for reference in ("diagonal", "largest_eigenvalue"):
        theta, G_train, _ = fold_fits(G, b, 0.0, reference)
        sse = held_out_sse(yy, theta, G, b)
        for f in range(3):
            tr, te = folds != f, folds == f
            beta = np.linalg.lstsq(X[tr], y[tr], rcond=None)[0]
            assert np.allclose(theta[f], beta, rtol=1e-6, atol=1e-9)
            assert sse[f] == pytest.approx(np.sum((y[te] - X[te] @ beta) ** 2), rel=1e-8)
            assert np.allclose(G_train[f], X[tr].T @ X[tr])
    with pytest.raises(ValueError, match="reference must be one of"):
        solve_normal(G[0], b[0], 1e-8, "trace")


def test_the_ridge_shrinks_toward_zero_as_it_grows():
    rng = np.random.default_rng(1)
    X = rng.standard_normal((50, 3))
    G, b = X.T @ X, X.T @ (X @ [1.0, 2.0, 3.0])
    for reference in ("diagonal", "largest_eigenvalue"):
        norms = [np.linalg.norm(solve_normal(G, b, r, reference)) for r in (0.0, 1e-2, 1.0, 1e2)]
        assert norms == sorted(norms, reverse=True) and norms[-1] < 0.1 * norms[0]


def test_one_rate_check_names_both_rates_and_the_file():
    check_model_rate(100.0 * (1 + 5e-5), 100.0)  # within the default tolerance
    with pytest.raises(DataError, match=r"^later\.csv: sampling rate 100\.01 Hz of the record differs from the "
                                        r"model's 100 Hz$"):
        check_model_rate(100.01, 100.0, what="record", source="later.csv")
    with pytest.raises(DataError):
        check_model_rate(100.0 * (1 + 5e-5), 100.0, tolerance=1e-6)


def test_the_diagnosis_refuses_data_at_another_rate(model):
    n = 2000
    data = PerturbationData(position=np.zeros(n), torque=np.zeros(n), scheduling=np.zeros(n), fs=200.0)
    with pytest.raises(DataError, match="sampling rate 200 Hz of the data differs from the model's 100 Hz"):
        diagnose(model, data)
