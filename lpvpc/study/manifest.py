"""The study manifest: one CSV row per record, read and checked before any work.

Columns (header row, any order; names are case-sensitive):

- ``record`` (needed): the record's unique name, a file-name-safe word;
- ``subject`` (needed): the subject it belongs to (sessions of one subject share it);
- ``group`` (needed): the group or condition the subject is compared in;
- ``pt`` and ``ut``, or ``data``: the trials as ``lpvpc identify`` takes them (perturbed and
  unperturbed), or one PT - UT file with a scheduling column;
- ``torque_sign``: 1 (default) or -1; ``position_unit``: rad (default) or deg;
- ``stationary``: true/false (default false): ``pt`` alone, a stationary trial;
- ``heldout``: the later fraction of the record held out, in (0, 1) (default: the study's);
- ``diagnose``: true/false (default: the study's): also diagnose the model on the held-out
  part (:func:`lpvpc.diagnosis.diagnose.diagnose`: which effect is missing, if any).

Paths are relative to the manifest's folder. Empty optional cells take the default. Any
other column is refused (a misspelt column would otherwise be silently ignored). Every
problem is a :class:`ManifestError` whose one line names the manifest, the row (its line
number in the file) and the column. Whether the files exist and hold usable data is not
checked here: a record whose file is missing or unusable fails on its own in the study
(:func:`lpvpc.study.run_study`), and the other records go on.

>>> import tempfile, pathlib
>>> with tempfile.TemporaryDirectory() as tmp:
...     p = pathlib.Path(tmp, "m.csv")
...     _ = p.write_text("record,subject,group,pt,ut\\nS1,S1,A,S1/PT.csv,S1/UT.csv\\nS1,S2,B,S2/PT.csv,\\n")
...     try:
...         read_manifest(p)
...     except ManifestError as exc:
...         print(str(exc).split(": ", 1)[1])
row 3 (record 'S1'), column record: 'S1' is already the record of row 2; give every record a unique name
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataError

__all__ = ["ManifestError", "ManifestRow", "read_manifest", "COLUMNS", "REQUIRED"]

#: Columns a manifest must have.
REQUIRED = ("record", "subject", "group")
#: Every column a manifest may have.
COLUMNS = ("record", "subject", "group", "pt", "ut", "data", "torque_sign", "position_unit", "stationary",
           "heldout", "diagnose")

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_TRUE = {"true", "1", "yes", "y"}
_FALSE = {"false", "0", "no", "n", ""}


class ManifestError(DataError):
    """A manifest that cannot be used: the message names the manifest, the row and the column."""


@dataclass(frozen=True)
class ManifestRow:
    """One record of a study (SI conventions as :func:`lpvpc.load_identification_data <lpvpc.io.identification_data.load_identification_data>` takes
    them).

    Parameters
    ----------
    record, subject, group : str
        The record's name (unique), its subject and its group.
    pt, ut, data : str or None
        The files as absolute paths (None where not given): ``pt`` and ``ut``, or ``data``.
    torque_sign : float or None
        The files' torque sign (None: the loader's default).
    position_unit : str or None
        The files' position unit (None: the loader's default).
    stationary : bool, default False
        ``pt`` alone, recorded around one position.
    heldout : float or None
        The held-out fraction (None: the study's default).
    diagnose : bool or None
        Diagnose the record's model on its held-out part (None: the study's default).
    line : int, default 0
        The row's line number in the manifest."""

    record: str
    subject: str
    group: str
    pt: str | None = None
    ut: str | None = None
    data: str | None = None
    torque_sign: float | None = None
    position_unit: str | None = None
    stationary: bool = False
    heldout: float | None = None
    diagnose: bool | None = None
    line: int = 0

    def files(self) -> list:
        """The record's files (those given), in the order pt, ut, data."""
        return [f for f in (self.pt, self.ut, self.data) if f]

    def settings(self) -> dict:
        """The per-record loading settings that change results (for the cache key)."""
        return {"torque_sign": self.torque_sign, "position_unit": self.position_unit,
                "stationary": self.stationary, "heldout": self.heldout, "diagnose": self.diagnose}


def read_manifest(path) -> list:
    """Read and check a study manifest (module docstring).

    Parameters
    ----------
    path : str or pathlib.Path
        The manifest (CSV).

    Returns
    -------
    list of ManifestRow
        The records, in file order.

    Raises
    ------
    ManifestError
        The first problem found, in one line naming row and column: a missing or unknown
        column, an empty required cell, a duplicate record name, files given as neither
        ``pt`` + ``ut`` nor ``data``, or a bad setting value.
    """
    path = Path(path)
    src = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise ManifestError(f"cannot read the manifest: {exc.strerror or exc}", src) from None
    reader = csv.reader(text.splitlines())
    try:
        header = next(reader)
    except StopIteration:
        raise ManifestError("the manifest is empty; its first line names the columns "
                            f"({', '.join(REQUIRED)}, and pt + ut or data)", src) from None
    header = [h.strip() for h in header]
    unknown = [h for h in header if h not in COLUMNS]
    if unknown:
        raise ManifestError(f"row 1 (header), column {unknown[0]!r}: unknown column; the columns are "
                            f"{', '.join(COLUMNS)}", src)
    dup = [h for i, h in enumerate(header) if h in header[:i]]
    if dup:
        raise ManifestError(f"row 1 (header), column {dup[0]!r}: given twice", src)
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise ManifestError(f"row 1 (header): missing column {missing[0]!r} (needed: {', '.join(REQUIRED)})", src)
    if not ({"pt", "data"} & set(header)):
        raise ManifestError("row 1 (header): no file columns; give pt and ut (or data)", src)
    base = path.parent
    rows, seen = [], {}
    for line, cells in enumerate(reader, start=2):
        if not any(c.strip() for c in cells):
            continue  # blank line
        if len(cells) > len(header):
            raise ManifestError(f"row {line}: {len(cells)} cells but {len(header)} columns in the header", src)
        cell = {h: (cells[i].strip() if i < len(cells) else "") for i, h in enumerate(header)}
        rows.append(_row(cell, line, base, seen, src))
    if not rows:
        raise ManifestError("the manifest has a header but no records", src)
    return rows


def _row(cell: dict, line: int, base: Path, seen: dict, src: str) -> ManifestRow:
    name = cell["record"]
    where = f"row {line}" + (f" (record {name!r})" if name else "")

    def bad(column, problem):
        return ManifestError(f"{where}, column {column}: {problem}", src)

    for c in REQUIRED:
        if not cell[c]:
            raise bad(c, "empty; every record needs its " + c)
    if not _NAME.match(name):
        raise bad("record", f"{name!r} is not a plain name (letters, digits, '.', '_', '-'; it names the "
                            "record's files in the study folder)")
    if name in seen:
        raise bad("record", f"{name!r} is already the record of row {seen[name]}; give every record a unique name")
    seen[name] = line
    stationary = cell.get("stationary", "").lower()
    if stationary not in _TRUE | _FALSE:
        raise bad("stationary", f"{cell['stationary']!r} is not true or false")
    stationary = stationary in _TRUE
    diagnose = cell.get("diagnose", "").lower()
    if diagnose not in _TRUE | _FALSE:
        raise bad("diagnose", f"{cell['diagnose']!r} is not true or false")
    diagnose = None if not diagnose else diagnose in _TRUE
    pt, ut, data = (cell.get(c, "") for c in ("pt", "ut", "data"))
    if data and (pt or ut):
        raise bad("data", "give either data or pt and ut, not both")
    if not data:
        if not pt:
            raise bad("pt", "empty; give pt and ut (or data)")
        if stationary and ut:
            raise bad("ut", "a stationary record has pt alone (leave ut empty or set stationary false)")
        if not stationary and not ut:
            raise bad("ut", "empty; give the unperturbed trial (or stationary true for a stationary trial)")
    sign = None
    if cell.get("torque_sign"):
        try:
            sign = float(cell["torque_sign"])
        except ValueError:
            sign = None
        if sign not in (1.0, -1.0):
            raise bad("torque_sign", f"{cell['torque_sign']!r} is not 1 or -1")
    unit = cell.get("position_unit") or None
    if unit is not None and unit not in ("rad", "deg"):
        raise bad("position_unit", f"{unit!r} is not rad or deg")
    heldout = None
    if cell.get("heldout"):
        try:
            heldout = float(cell["heldout"])
        except ValueError:
            heldout = float("nan")
        if not 0.0 < heldout < 1.0:
            raise bad("heldout", f"{cell['heldout']!r} is not a fraction between 0 and 1 (e.g. 0.3: the last 30 %)")

    def resolve(f):
        return str((base / f).resolve()) if f else None

    return ManifestRow(record=name, subject=cell["subject"], group=cell["group"], pt=resolve(pt), ut=resolve(ut),
                       data=resolve(data), torque_sign=sign, position_unit=unit, stationary=stationary,
                       heldout=heldout, diagnose=diagnose, line=line)
