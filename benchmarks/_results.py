"""How the benchmarks record their tables: a file in benchmarks/results/, the table's lines
joined by newlines with one trailing newline."""

from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def write_results(target, lines, *, echo=False) -> Path:
    """Write ``lines`` to ``target`` (a file name in benchmarks/results/, or a Path used as
    given); with ``echo`` print the table first; then print where it went."""
    path = target if isinstance(target, Path) else RESULTS / target
    text = "\n".join(lines) + "\n"
    if echo:
        print(text)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    print(f"written to {path}")
    return path


#: rad RMS in each trial: the lab's pilot trial's position noise floor (docs/design_notes.md,
#: "Position noise floor"), the value the population benchmarks are checked with
PILOT_POSITION_NOISE = 5e-5


def add_position_noise_option(parser, default=0.0):
    """The population benchmarks' ``--position-noise RAD`` option: white noise of that RMS in
    each trial's recorded position (the population has none by default)."""
    parser.add_argument("--position-noise", type=float, default=default, metavar="RAD",
                        help=f"white noise of this RMS in each trial's recorded position (default {default:g}; the "
                             f"lab's pilot trial: about {PILOT_POSITION_NOISE:g})")


def position_noise_text(noise) -> str:
    """The sentence a results file states its position noise with ("" without any)."""
    return (f" Position sensor noise: white, {noise:g} rad RMS in each trial's recorded position (the lab's pilot "
            f"trial's floor is about {PILOT_POSITION_NOISE:g}; docs/design_notes.md, \"Position noise floor\")."
            if noise else "")
