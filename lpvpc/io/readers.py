"""Reading CSV and MATLAB ``.mat`` files into trials (:func:`~lpvpc.io.readers.load_trial`).

A file's columns (or a ``.mat`` record's channels, see :mod:`lpvpc.io.matfiles`) are picked by
role (time, position, torque, optional channels), converted to SI
(:mod:`lpvpc.io.conventions`) and checked (:func:`lpvpc.io.trial.check_trial`).
"""

from __future__ import annotations

import csv
import io
import logging
import os
from pathlib import Path

import numpy as np

from .conventions import _check_settings, _check_time_unit, _refuse_degrees, _to_si
from ..errors import DataError
from .matfiles import split_variable
from .trial import OPTIONAL_CHANNELS, REQUIRED_CHANNELS, Trial, _plural, check_trial


# EMG columns of a perturbation file (PT - UT already formed): the PT and the UT trial's.
PERTURBATION_EMG = ("emg", "emg_ut")

_log = logging.getLogger(__name__)  # notes (e.g. ignored CSV columns); the CLI shows them with --verbose


# --------------------------------------------------------------------------- reading files


def _read_csv(path: Path, channels=None) -> dict[str, np.ndarray]:
    """Columns of a CSV file with one header row (leading ``#`` comment lines are skipped).
    ``channels`` maps roles to the file's own column names (``{"position": "Pert (rad)"}``,
    case-insensitive); a column already named after a mapped role is then not read.
    A file larger than the per-variable limit (:func:`lpvpc.io.matfiles.max_variable_bytes`,
    1 GiB unless set) is refused before it is read."""
    from .matfiles import max_variable_bytes, over_limit

    limit = max_variable_bytes()
    size = os.path.getsize(path)
    if size > limit:  # the text is held in memory below: bounded by the limit, not by the file
        raise DataError([over_limit("the file", size, limit)], source=str(path))
    try:
        text = path.read_text(encoding="utf-8-sig")  # tolerate a BOM (spreadsheet exports)
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError([f"cannot read file: {exc}"], source=str(path)) from exc
    lines = text.splitlines()
    header_at = None
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            # numpy.savetxt's default writes the header as a comment: accept that too.
            names = [c.strip().lower() for c in stripped.lstrip("#").split(",")]
            if "time" in names:
                header_at = i
                break
            continue
        header_at = i
        break
    if header_at is None:
        raise DataError(["empty file (no header row)"], source=str(path))
    names = [c.strip().lower() for c in lines[header_at].strip().lstrip("#").split(",")]
    if channels:
        names = _renamed_columns(names, channels, path)
    duplicates = sorted({c for c in names if names.count(c) > 1})
    problems = [f"duplicate column '{c}'" for c in duplicates]
    problems += [f"empty column name at position {i + 1}" for i, c in enumerate(names) if not c]
    if problems:
        raise DataError(problems, source=str(path))
    body = [ln for ln in lines[header_at + 1:] if ln.strip() and not ln.lstrip().startswith("#")]
    # Columns the loaders know are read as numbers; any other column (a text notes column,
    # a trigger, a label) is ignored, whatever it holds. Every row still needs every field.
    known = set(REQUIRED_CHANNELS + OPTIONAL_CHANNELS + PERTURBATION_EMG)
    use = [i for i, c in enumerate(names) if c in known]
    ignored = [c for c in names if c not in known]
    if ignored:
        _log.info("%s: ignored column(s) %s (not channels lpvpc reads)", path, ", ".join(ignored))
    if not body or not use:
        return _Table({names[i]: np.empty(0) for i in use}, names)
    values = None
    if '"' not in text and all(ln.count(",") == len(names) - 1 for ln in body):
        try:
            values = np.loadtxt(body, delimiter=",", ndmin=2, dtype=float, usecols=use)
        except ValueError:
            values = None
    if values is None:  # quoted fields, ragged or unparsable rows: the careful parse
        values, problems = _csv_rows(body, names, use, first_line=header_at + 2)
        if problems:
            raise DataError(problems, source=str(path))
    return _Table({names[i]: values[:, k] for k, i in enumerate(use)}, names)


def _renamed_columns(names: list[str], channels: dict, path: Path) -> list[str]:
    """The header with each mapped column renamed to its role (columns that carried a
    mapped role's name before are renamed away, so they are not read)."""
    known = set(REQUIRED_CHANNELS + OPTIONAL_CHANNELS + PERTURBATION_EMG)
    problems = []
    unknown = sorted(set(channels) - known)
    if unknown:
        problems.append(f"unknown channel role(s) {', '.join(unknown)} (roles: {', '.join(sorted(known))})")
    wanted = {str(col).strip().lower(): role for role, col in channels.items()}
    for col, role in wanted.items():
        if col not in names:
            problems.append(f"no column '{col}' for {role} (columns found: {', '.join(names)})")
    if len(wanted) < len(channels):
        problems.append("two roles name the same column")
    if problems:
        raise DataError(problems, source=str(path))
    mapped = set(wanted.values())
    return [wanted[c] if c in wanted else f"{c} (not read: --channel {c}=...)" if c in mapped else c for c in names]


class _Table(dict):
    """Channels read from a file; ``columns``: every column of the file (also those ignored)."""

    def __init__(self, channels, columns):
        super().__init__(channels)
        self.columns = list(columns)


def _csv_rows(body: list[str], names: list[str], use: list[int], first_line: int):
    """Slow parse (quoted fields allowed), after the fast one failed: the ``use`` columns as
    an array, or the problems (which rows and fields are bad).

    Line numbers are approximate when comment or blank lines sit between data rows.
    """
    wrong_width: list[int] = []
    unparsable: dict[str, list[int]] = {}
    rows = []
    for k, row in enumerate(csv.reader(io.StringIO("\n".join(body)))):
        line = first_line + k
        if len(row) != len(names):
            wrong_width.append(line)
            continue
        out = []
        for i in use:
            try:
                out.append(float(row[i]))
            except ValueError:
                unparsable.setdefault(names[i], []).append(line)
        rows.append(out)
    problems = []
    if wrong_width:
        problems.append(
            f"{_plural(len(wrong_width), 'row')} without {len(names)} fields, first at line {wrong_width[0]}"
        )
    for name, at in unparsable.items():
        problems.append(f"column '{name}': {_plural(len(at), 'value')} not a number, first at line {at[0]}")
    if problems:
        return None, problems
    return np.array(rows, dtype=float).reshape(len(rows), len(use)), []


def _read_mat(path: Path, required, optional, variable=None, channels=None) -> dict[str, np.ndarray]:
    """Channels of a MATLAB file by role (``time``, ``position``, ...): the lab's ``nldat``
    objects, structs, matrices or plain vectors, v4 to v7.3 (:mod:`lpvpc.io.matfiles`)."""
    from lpvpc.io.matfiles import needed_variables, read_mat, select_channels

    skipped: list = []  # variables over the size limit, not read
    records = read_mat(path, needed_variables(variable, channels), skipped)
    try:
        return select_channels(records, required, optional, channels=channels, variable=variable, source=str(path))
    except DataError as exc:
        if skipped:
            raise DataError(list(exc.problems) + skipped, source=str(path)) from None
        raise


def _path_and_variable(path, variable):
    path, named = split_variable(path)
    return path, (named if named is not None else variable)


def _read_table(path, required=REQUIRED_CHANNELS, optional=OPTIONAL_CHANNELS, *, variable=None,
                channels=None) -> tuple[dict[str, np.ndarray], Path]:
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".mat"):
        raise DataError([f"unknown file extension '{path.suffix}' (expected .csv or .mat)"], source=str(path))
    if not path.is_file():
        raise DataError(["no such file"], source=str(path))
    if os.path.getsize(path) == 0:
        raise DataError(["empty file"], source=str(path))
    if suffix == ".csv":
        if variable is not None:
            raise DataError([f"a variable ({variable}) names a variable in .mat files; a CSV file holds one table"],
                            source=str(path))
        return _read_csv(path, channels), path
    return _read_mat(path, required, optional, variable, channels), path


def _require(table: dict, required, path) -> None:
    missing = [c for c in required if c not in table]
    if missing:
        found = ", ".join(getattr(table, "columns", table)) or "none"
        listed = ", ".join(f"'{c}'" for c in missing)
        raise DataError([f"missing required column{'s' if len(missing) > 1 else ''} {listed} (columns found: "
                         f"{found}); a column named otherwise is chosen with channels={{'{missing[0]}': COLUMN}} "
                         f"(--channel {missing[0]}=COLUMN)"], source=str(path))


def _name(path: Path, variable) -> str:
    return f"{path.stem}:{variable}" if variable else path.stem


def _trial_from_table(table, path, name, required, extra_channels=()) -> Trial:
    _require(table, required, path)
    channels = {c: table[c] for c in OPTIONAL_CHANNELS + tuple(extra_channels) if c in table}
    trial = Trial(table["time"], table["position"], table["torque"], channels, name or path.stem)
    check_trial(trial, source=str(path))
    return trial


def load_trial(path, *, position_unit: str = "rad", torque_sign: float = +1.0, name=None, variable=None,
               channels=None, time_unit: str = "s", degrees: str = "warn") -> Trial:
    """Load one trial from CSV or MATLAB ``.mat`` (v4 to v7.3, the lab's ``nldat`` objects too).

    Required columns/variables: ``time`` (s), ``position``, ``torque``; optional ``emg``,
    ``command``, ``scheduling``; other columns are ignored.

    Parameters
    ----------
    path : str or pathlib.Path
        The CSV or .mat file (``"file.mat:NAME"`` names the variable too).
    position_unit : {"rad", "deg"}, default "rad"
        The unit of position, command and scheduling in the file.
    torque_sign : {1.0, -1.0}, default 1.0
        Multiplies torque (N m) to bring the lab's sign convention to the package's.
    name : str, optional
        The trial's name in messages; default the file name.
    variable : str, optional
        In a .mat file, the variable (e.g. an ``nldat`` object); chosen automatically when
        only one fits (:func:`lpvpc.io.matfiles.select_channels`).
    channels : dict, optional
        In a .mat file, roles to channel names (``{"position": "pos1", "torque": "tq1"}``);
        time comes from a ``time`` channel or the variable's sample period.
    time_unit : {"s", "ms"}, default "s"
        The unit of a time column.
    degrees : {"warn", "refuse"}, default "warn"
        When angles read as rad look like degrees: warn (:class:`~lpvpc.errors.UnitWarning`),
        or refuse where a result computed from them would be meaningless (a held-out record,
        a trial a model is fitted to).

    Returns
    -------
    lpvpc.io.trial.Trial
        Time (s), position (rad), torque (N m) and the optional channels.

    Raises
    ------
    lpvpc.errors.DataError
        An unreadable file, missing columns, an uneven time base, NaN values, or (with
        ``degrees="refuse"``) angles that look like degrees; one message listing every
        problem.
    """
    _check_settings(position_unit, torque_sign)
    if degrees not in ("warn", "refuse"):
        raise ValueError(f"degrees must be 'warn' or 'refuse', got {degrees!r}")
    _check_time_unit(time_unit)
    path, variable = _path_and_variable(path, variable)
    table, path = _read_table(path, variable=variable, channels=channels)
    trial = _trial_from_table(table, path, name or _name(path, variable), REQUIRED_CHANNELS)
    if degrees == "refuse":
        _refuse_degrees([trial], position_unit)
    return _to_si(trial, position_unit, torque_sign, str(path), time_unit)
