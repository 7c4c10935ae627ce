"""Where the lab's public recordings are (shared by the real-data benchmarks).

The recordings are not part of the project (see the README there): the benchmarks look for
them in ``$LPVPC_REAL_DATA`` or in ``shared/real`` next to the checkout (``../shared/real``),
and skip with a message when they are absent.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def real_data_dir() -> Path | None:
    env = os.environ.get("LPVPC_REAL_DATA")
    candidates = [Path(env)] if env else []
    candidates += [ROOT.parent / "shared" / "real", ROOT.parent.parent / "shared" / "real"]
    for c in candidates:
        if (c / "pilot_ident.csv").is_file() or (c / "experimental_data.mat").is_file():
            return c
    return None


def require(name: str) -> Path:
    """Path of the recording ``name``, or exit 0 with a message saying why the benchmark skips."""
    folder = real_data_dir()
    if folder is None or not (folder / name).is_file():
        print(f"skipped: {name} not found (set LPVPC_REAL_DATA or put the lab's recordings in ../shared/real)")
        sys.exit(0)
    return folder / name
