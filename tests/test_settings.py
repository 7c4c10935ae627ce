"""Each estimator setting is declared once: the signature of ``LPVPCEstimator.__init__``.
``get_params`` is derived from it, and the command line's ``identify`` options are checked
against it: each option that sets an estimator setting defaults to None (the estimator's
default applies, stated once), and each setting is an option or is named here as one the
command line leaves at its default, with the reason."""

import inspect

import pytest

from lpvpc import LPVPCEstimator
from lpvpc.cli import build_parser

#: settings the command line does not offer, and why
NOT_ON_THE_COMMAND_LINE = {
    "velocity_basis": "the model-rate velocity basis; the high-rate one is an option",
    "min_state_order": "auto's smallest order (1) is never worth raising by hand",
    "refine": "the pole refinement: a switch for the method's ablations in Python",
    "stationary_range": "the span below which a record is one position (--stationary names such trials)",
    "causal_derivatives": "the difference stencil of the causal form: a Python-level choice",
    "stationary_delays": "the delays tried on stationary trials: a Python-level choice",
    "elastic_curvature": "chosen by the structure selection; set in Python to hold it",
    "max_reflex_time_constant": "a guard on the reflex poles: a Python-level choice",
    "structure_fixed": "the command line fills it with the options given (they stay fixed)",
}


def identify_options() -> dict:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, type(parser._subparsers._group_actions[0])))
    return {a.dest: a for a in sub.choices["identify"]._actions}


def test_get_params_is_the_signature():
    names = [p for p in inspect.signature(LPVPCEstimator.__init__).parameters if p != "self"]
    est = LPVPCEstimator()
    assert list(est.get_params()) == names
    defaults = {k: p.default for k, p in inspect.signature(LPVPCEstimator.__init__).parameters.items()
                if k not in ("self", "structure_fixed")}
    assert {k: v for k, v in est.get_params().items() if k != "structure_fixed"} == defaults
    clone = LPVPCEstimator(**est.set_params(intrinsic_order=3).get_params())
    assert clone.intrinsic_order == 3 and clone.get_params() == est.get_params()


def test_command_line_options_match_the_estimator_settings():
    options = identify_options()
    names = LPVPCEstimator._param_names()
    missing = [n for n in names if n not in options and n not in NOT_ON_THE_COMMAND_LINE]
    assert not missing, f"estimator settings with no identify option and no reason here: {missing}"
    stale = [n for n in NOT_ON_THE_COMMAND_LINE if n not in names or n in options]
    assert not stale, f"NOT_ON_THE_COMMAND_LINE names no longer right: {stale}"
    restated = {n: options[n].default for n in names if n in options and options[n].default is not None}
    assert not restated, f"identify options that restate an estimator default (give None): {restated}"


@pytest.mark.parametrize("name", ["intrinsic_order", "irf_length", "max_iter"])
def test_help_quotes_the_signature_default(name):
    default = inspect.signature(LPVPCEstimator.__init__).parameters[name].default
    assert f"default {default:g}" in identify_options()[name].help


def test_improve_steps_default_is_the_library_s():
    """``lpvpc improve --max-steps`` defaults to None (the library's MAX_STEPS applies) and its
    help quotes that value."""
    from lpvpc.diagnosis.improve import MAX_STEPS

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, type(parser._subparsers._group_actions[0])))
    option = next(a for a in sub.choices["improve"]._actions if a.dest == "max_steps")
    assert option.default is None and f"(default {MAX_STEPS})" in option.help
