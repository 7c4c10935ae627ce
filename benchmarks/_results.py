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
