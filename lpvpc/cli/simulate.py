"""``lpvpc simulate``: a virtual subject, a subject of the population, or a virtual cohort."""

from __future__ import annotations

import argparse

from ._common import _UsageError, _add_quiet_arg, _positive_float


def _simulate_population(args) -> int:
    """simulate --population-seed N: the population's subject N (lpvpc.simulation.population)."""
    from ..simulation.population import POPULATION_EFFECTS, draw_subject, write_subject

    fixed = [opt for opt, v in (("--seed", args.seed), ("--snr", args.snr), ("--perturbation", args.perturbation),
                                ("--stiffness-family", args.stiffness_family)) if v is not None]
    if fixed:
        raise _UsageError(f"{', '.join(fixed)} cannot be given with --population-seed (the subject draws them)")
    if args.population_seed < 0:
        raise _UsageError(f"--population-seed must be >= 0, got {args.population_seed}")
    if len(args.effect) > 1:
        raise _UsageError("--population-seed takes at most one --effect")
    effect = args.effect[0] if args.effect else None
    if effect is not None and effect not in POPULATION_EFFECTS:
        raise _UsageError(f"unknown population effect {effect!r} (known: {', '.join(POPULATION_EFFECTS)})")
    if args.form is not None and (effect is None or args.form not in POPULATION_EFFECTS[effect]):
        known = f"{effect}'s forms: {', '.join(POPULATION_EFFECTS[effect])}" if effect else "--form needs --effect"
        raise _UsageError(f"unknown form {args.form!r} ({known})")
    subject = draw_subject(args.population_seed, effect, args.form)
    paths = write_subject(subject, args.out, fs_out=args.fs, duration=args.duration)
    eff = f", effect {effect} ({subject.form})" if effect else ""
    print(f"population subject {args.population_seed}: {args.duration:g} s at {args.fs:g} Hz, SNR {subject.snr_db:.1f} dB, "
          f"perturbation {subject.design}, stiffness {subject.stiffness_form}{eff}")
    for path in paths.values():
        print(path)
    return 0


def _simulate_cohort(args) -> int:
    """simulate --cohort N: a virtual cohort in two groups with its manifest (lpvpc.study.cohort)."""
    from ..study.cohort import write_cohort

    fixed = [opt for opt, v in (("--seed", args.seed), ("--snr", args.snr), ("--perturbation", args.perturbation),
                                ("--stiffness-family", args.stiffness_family), ("--form", args.form))
             if v is not None] + (["--effect"] if args.effect else [])
    if fixed:
        raise _UsageError(f"{', '.join(fixed)} cannot be given with --cohort (the population draws the subjects)")
    if args.cohort < 2:
        raise _UsageError(f"--cohort needs at least 2 subjects (one per group), got {args.cohort}")
    first = args.population_seed or 0
    if first < 0:
        raise _UsageError(f"--population-seed must be >= 0, got {first}")
    design = "within" if args.within else "between"
    paths = write_cohort(args.out, args.cohort, first_seed=first, null=args.null, duration=args.duration, fs=args.fs,
                         design=design)
    what = "null cohort (no difference)" if args.null else "cohort (patient: K x1.5 toward dorsiflexion, reflex gain x2)"
    print(f"virtual {what}: {args.cohort} subjects"
          + (", each recorded in both groups" if args.within else "")
          + f", population seeds {first}..{first + args.cohort - 1}, {args.duration:g} s at {args.fs:g} Hz")
    for path in paths.values():
        print(path)
    return 0


def run(args) -> int:
    """Simulate a virtual subject, a population subject (``--population-seed``) or a cohort
    (``--cohort``), write its files and print what was simulated and where; returns 0."""
    from ..simulation.simulate import EFFECTS, FS_SIM, PERTURBATIONS, write_dataset

    q = FS_SIM / args.fs
    if args.fs <= 0 or abs(q - round(q)) > 1e-9:
        raise _UsageError(f"--fs {args.fs:g} Hz must divide the simulation rate {FS_SIM:g} Hz (e.g. 1000 or 100)")
    if args.duration * args.fs < 100:
        raise _UsageError(f"--duration {args.duration:g} s is too short (need at least 100 samples)")
    if args.cohort is not None:
        return _simulate_cohort(args)
    if args.null or args.within:
        raise _UsageError(f"{'--null' if args.null else '--within'} needs --cohort N")
    if args.population_seed is not None:
        return _simulate_population(args)
    if args.form is not None:
        raise _UsageError("--form needs --population-seed")
    for name, default in (("seed", 0), ("snr", 18.0), ("perturbation", "pralds"), ("stiffness_family", "standard")):
        if getattr(args, name) is None:
            setattr(args, name, default)

    unknown = [e for e in args.effect if e not in EFFECTS]
    if unknown:
        raise _UsageError(f"unknown effect {', '.join(map(repr, unknown))} (known: {', '.join(sorted(EFFECTS))})")
    if args.perturbation not in PERTURBATIONS:
        raise _UsageError(f"unknown perturbation {args.perturbation!r} (known: {', '.join(sorted(PERTURBATIONS))})")
    from ..simulation.subject import STIFFNESS_FAMILIES

    if args.stiffness_family not in STIFFNESS_FAMILIES:
        raise _UsageError(f"unknown stiffness family {args.stiffness_family!r} (known: {', '.join(STIFFNESS_FAMILIES)})")
    paths = write_dataset(args.out, seed=args.seed, fs_out=args.fs, snr_db=args.snr,
                          effects=tuple(args.effect), duration=args.duration, perturbation=args.perturbation,
                          stiffness_family=args.stiffness_family)
    effects = f", effects: {', '.join(args.effect)}" if args.effect else ""
    print(f"virtual subject, seed {args.seed}, {args.duration:g} s at {args.fs:g} Hz, SNR {args.snr:g} dB, "
          f"perturbation {args.perturbation}{effects}"
          + ("" if args.stiffness_family == "standard" else f", stiffness {args.stiffness_family}"))
    for path in paths.values():
        print(path)
    return 0


class _SimulateHelp(argparse.HelpFormatter):
    """simulate --help: the simulator's effects listed when the help is shown (the simulator
    imports scipy.signal; building the parser must not)."""

    def _get_help_string(self, action):
        text = super()._get_help_string(action)
        return text.replace("{simulated_effects}", _simulated_effects()) if text else text


def _simulated_effects() -> str:
    """The simulator's effects: those of the catalog (identify --effect), then the others."""
    from ..models.effects import CATALOG
    from ..simulation.simulate import EFFECTS

    outside = [e for e in EFFECTS if e not in CATALOG]
    return (", ".join(e for e in CATALOG if e in EFFECTS)
            + (f"; outside the catalog (no model term names them): {', '.join(outside)}" if outside else ""))


# --------------------------------------------------------------------------- main


def add_parser(sub):
    """Register the ``simulate`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc simulate'
    """
    p = sub.add_parser("simulate", help="write a virtual-subject data set with its truth",
                       formatter_class=_SimulateHelp,
                       description="Simulate the virtual subject: identification and novel PT/UT trials, "
                                   "truth.json and truth_*.npz.")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--population-seed", type=int, default=None, metavar="N",
                   help="simulate subject N of the population of virtual subjects (parameters, stiffness shape, "
                        "noise, EMG and perturbation design drawn from published ranges; docs/guide/population.md); "
                        "--effect then names one population effect and --form its form")
    p.add_argument("--form", default=None, metavar="FORM",
                   help="with --population-seed and --effect: the effect's form (default: drawn)")
    p.add_argument("--snr", type=float, default=None, metavar="DB",
                   help="SNR of the perturbation torque in dB (default 18; inf: no noise)")
    p.add_argument("--fs", type=_positive_float, default=1000.0, metavar="HZ",
                   help="output sampling rate, 1000 or 100 Hz (default 1000)")
    p.add_argument("--effect", action="extend", nargs="+", default=[], metavar="NAME",
                   help="switch on a physical effect the LPV-PC model lacks (repeatable): {simulated_effects}")
    p.add_argument("--duration", type=_positive_float, default=120.0, metavar="S",
                   help="length of each trial in s (default 120)")
    p.add_argument("--perturbation", default=None, metavar="NAME",
                   help="pralds: levels uniform in +-0.04 rad (default); lab_pulses: the lab pilot trial's "
                        "design, holds alternating between 0 and +-0.02..0.04 rad; prbs: +-0.04 rad switching "
                        "every 50-150 ms (no quiet windows)")
    p.add_argument("--stiffness-family", default=None, metavar="NAME",
                   help="shape of the elastic stiffness K(theta): standard (default), sum_of_exponentials "
                        "(steeper textbook form), piecewise (piecewise linear with a kink), polynomial (a cubic)")
    p.add_argument("--cohort", type=int, default=None, metavar="N",
                   help="write a virtual cohort of N population subjects in two groups (patient: K x1.5 toward "
                        "dorsiflexion, reflex gain x2) with manifest.csv and truth.json for lpvpc study; "
                        "--population-seed gives the first subject's seed (default 0)")
    p.add_argument("--null", action="store_true", help="with --cohort: no difference between the groups")
    p.add_argument("--within", action="store_true",
                   help="with --cohort: every subject recorded in both groups (records SUBJECT-GROUP, a paired "
                        "comparison in lpvpc study; default: each subject in one group)")
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)
    p.set_defaults(func=run)
    return p
