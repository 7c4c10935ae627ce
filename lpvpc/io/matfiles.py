"""MATLAB ``.mat`` files: the lab's ``nldat`` objects, plain arrays and structs, any version.

A file is read into *records*: named groups of equally sampled channels.

- an ``nldat`` object (the lab's format: a MATLAB class object, classdef or old-style, or a
  struct with the same fields) is one record: ``dataSet`` (N x channels) with channel
  names from ``chanNames``, sample period ``domainIncr`` (s), start ``domainStart`` (s);
- a struct's vector fields form one record (nested structs and objects are records of
  their own, named ``outer.inner``); a scalar field ``fs``/``Fs`` (Hz) or ``dt``/``Ts`` (s)
  gives its sample period;
- a matrix variable (N x k) is a record whose channels are its columns ``1`` .. ``k``;
- the elements of cell arrays and of arrays of objects or structs are records named
  ``name{k}`` and ``name(k)`` (several trials kept in one variable);
- the file's top-level vectors form one record (named ``(top level)``), e.g. ``time``,
  ``position``, ``torque`` as earlier versions of this package read them.

Which channels are position, torque, ... is chosen by :func:`select_channels`: by name when
the caller says so (``channels={"position": "pos1"}``, ``variable="z_df"``), otherwise
automatically when only one choice fits; an ambiguous or empty choice is one DataError that
lists the variables and channels found. MATLAB v4/v5/v7 and v7.3 (HDF5) files are read with
``mat-io`` (which reads class objects; ``scipy.io.loadmat`` cannot), plain v5 files with
``scipy.io`` as a fallback. Units are not converted here (see :mod:`lpvpc.io`).

Bounded reading: before anything is read, the size each variable declares is taken from the
file's headers alone (:func:`declared_sizes`: v5 element tags and array dimensions, also
inside compressed elements; v7.3 HDF5 dataset shapes, following MATLAB's references).
Only the variables a read needs are loaded (a named variable: that one); a needed variable
declaring more than :func:`max_variable_bytes` is one DataError naming the limit, an
unrelated one is skipped without being read.
"""

from __future__ import annotations

import os
import re
import struct
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError

TOP_LEVEL = "(top level)"
# Channel names (case-insensitive) a role is recognised by when the caller names none. An
# exact name wins; otherwise a unique name containing one of the patterns.
ROLE_NAMES = {
    "time": ("time", "t"),
    "position": ("position",),
    "torque": ("torque",),
    "scheduling": ("scheduling",),
    "emg": ("emg",),
    "emg_ut": ("emg_ut",),
    "command": ("command",),
}
ROLE_PATTERNS = {
    "position": ("pos", "angle"),
    "torque": ("tq", "torque", "trq", "moment"),
    "scheduling": ("sched", "rho"),
}
# A record of this name holds the scheduling variable in the lab's files ('sv' of the pilot).
SCHEDULING_RECORDS = ("sv", "scheduling")
RATE_FIELDS = {"fs": "rate", "samplingrate": "rate", "sampling_rate": "rate", "dt": "period", "ts": "period",
               "domainincr": "period"}


@dataclass
class Record:
    """The channels (name -> 1-D float array) of one variable of a .mat file, with the
    sample period (s) and start time (s) when the file says them. Channels of unequal
    length are kept as found (the trial checks report them).

    A matrix variable sampled at 1 kHz, as :func:`read_mat` returns it (a matrix's columns
    are channels ``1``, ``2``, ...):

    >>> r = Record("trial", "matrix", {"1": np.zeros(3000), "2": np.ones(3000)}, period=0.001)
    >>> r.describe(), r.n
    ('trial (matrix, 3000 samples at 1000 Hz: 1, 2)', 3000)
    >>> r.times()[:3]  # s
    array([0.   , 0.001, 0.002])
    """

    name: str
    kind: str  # "nldat", "struct", "matrix" or "variables"
    channels: dict = field(default_factory=dict)
    period: float | None = None
    start: float = 0.0
    time: np.ndarray | None = None  # explicit sample times (nldat domainValues), if any

    @property
    def n(self) -> int:
        lengths = {len(x) for x in self.channels.values()}
        return lengths.pop() if len(lengths) == 1 else 0

    def describe(self) -> str:
        """e.g. ``z_df (nldat, 60000 samples at 1000 Hz: pos1, tq1)``."""
        lengths = sorted({len(x) for x in self.channels.values()}) or [0]
        size = f"{lengths[0]} samples" if len(lengths) == 1 else "samples " + "/".join(map(str, lengths))
        rate = f" at {1.0 / self.period:.6g} Hz" if self.period else ""
        return f"{self.name} ({self.kind}, {size}{rate}: {', '.join(self.channels) or 'no channels'})"

    def times(self) -> np.ndarray | None:
        """Sample times (s) from the record's domain, or None if it has none."""
        if self.time is not None:
            return self.time
        if self.period:
            return self.start + np.arange(self.n) * self.period
        return None


# --------------------------------------------------------------------------- declared sizes
MAX_VARIABLE_BYTES = 1 << 30  #: 1 GiB per variable (a 30-minute 1 kHz record of 6 channels is 86 MB)
LIMIT_ENV = "LPVPC_MAX_VARIABLE_BYTES"  # environment variable that sets another limit (bytes)
SUBSYSTEM = "(class object data)"  #: where MATLAB keeps classdef objects' contents (v5 and v7.3)


def max_variable_bytes() -> int:
    """The limit (bytes) on what one variable of a .mat file (or a CSV file) may declare:
    ``$LPVPC_MAX_VARIABLE_BYTES`` if set, else :data:`MAX_VARIABLE_BYTES` (1 GiB).

    >>> os.environ[LIMIT_ENV] = "5e8"; max_variable_bytes()
    500000000
    >>> del os.environ[LIMIT_ENV]; max_variable_bytes() == MAX_VARIABLE_BYTES
    True
    """
    text = os.environ.get(LIMIT_ENV, "").strip()
    if not text:
        return MAX_VARIABLE_BYTES
    try:
        value = int(float(text))
    except ValueError:
        value = 0
    if value <= 0:
        raise DataError([f"{LIMIT_ENV}={text!r} must be a positive number of bytes"])
    return value


def size_text(n: int) -> str:
    """``1073741824`` -> ``'1 GiB'``; ``8e9`` -> ``'7.45 GiB'``.

    >>> size_text(1 << 30), size_text(8 * 10**9), size_text(512)
    ('1 GiB', '7.45 GiB', '512 bytes')
    """
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} bytes"


def over_limit(what: str, n: int, limit: int) -> str:
    """The one-line problem of a variable or file over the limit.

    >>> over_limit("variable 'junk'", 8 * 10**9, 1 << 30)
    "variable 'junk' declares 7.45 GiB of data, over the limit of 1 GiB (lpvpc.io.matfiles.MAX_VARIABLE_BYTES; set LPVPC_MAX_VARIABLE_BYTES=BYTES to read it)"
    """
    return (f"{what} declares {size_text(n)} of data, over the limit of {size_text(limit)} "
            f"(lpvpc.io.matfiles.MAX_VARIABLE_BYTES; set {LIMIT_ENV}=BYTES to read it)")


def declared_sizes(path) -> dict | None:
    """{variable: bytes its data declare} from a .mat file's headers, without reading the
    data (a compressed v5 element: its first few hundred bytes); the class objects' store is
    listed as :data:`SUBSYSTEM`; v4 files from their 20-byte variable headers (None if those
    do not parse: the file is then read unchecked). Raises DataError if an HDF5 file's
    structure cannot be read.

    >>> import tempfile, scipy.io
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     scipy.io.savemat(f"{tmp}/t.mat", {"torque": np.zeros(1000)}, do_compression=True)
    ...     declared_sizes(f"{tmp}/t.mat")["torque"] >= 8000
    True
    """
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(128)
        f.seek(512)
        hdf = f.read(8) == b"\x89HDF\r\n\x1a\n"
    if hdf:
        return _hdf5_sizes(path)
    if len(head) == 128 and head[124:128] in (b"\x00\x01IM", b"\x01\x00MI"):
        return _v5_sizes(path, "<" if head[126:128] == b"IM" else ">")
    return _v4_sizes(path)


_V4_ITEM_BYTES = (8, 4, 4, 2, 2, 1)  # by the type's precision digit: double, single, int32, int16, uint16, uint8


def _v4_sizes(path: Path) -> dict | None:
    """A v4 file's variables: 20-byte headers (type, rows, columns, imaginary flag, name
    length) each followed by the name and the data. None if the headers do not parse."""
    sizes: dict = {}
    end = path.stat().st_size
    with open(path, "rb") as f:
        pos = 0
        while pos + 20 <= end:
            f.seek(pos)
            raw = f.read(20)
            for endian in "<>":
                mopt, rows, cols, imag, namlen = struct.unpack(endian + "iiiii", raw)
                if 0 <= mopt < 5000 and rows >= 0 and cols >= 0 and 0 < namlen < 1 << 16:
                    break
            else:
                return None
            precision = mopt % 100 // 10
            if precision >= len(_V4_ITEM_BYTES):
                return None
            name = f.read(namlen).split(b"\x00")[0].decode("ascii", "replace")
            size = rows * cols * _V4_ITEM_BYTES[precision] * (2 if imag else 1)
            sizes[name] = sizes.get(name, 0) + size
            pos += 20 + namlen + size
    return sizes


_MI_MATRIX, _MI_COMPRESSED = 14, 15


def _v5_sizes(path: Path, endian: str) -> dict:
    sizes: dict = {}
    end = path.stat().st_size
    with open(path, "rb") as f:
        pos = 128
        while pos + 8 <= end:
            f.seek(pos)
            mtype, nbytes = struct.unpack(endian + "II", f.read(8))
            if mtype == _MI_COMPRESSED:
                head = zlib.decompressobj().decompress(f.read(min(nbytes, 1 << 16)), 4096)
                if len(head) < 8:
                    break
                inner_type, inner_bytes = struct.unpack(endian + "II", head[:8])
                name, values = _v5_matrix_header(head[8:], endian) if inner_type == _MI_MATRIX else ("", 0)
                size = max(inner_bytes, values * 8)
            elif mtype == _MI_MATRIX:
                name, values = _v5_matrix_header(f.read(min(nbytes, 4096)), endian)
                size = max(nbytes, values * 8)
            else:
                name, size = "", nbytes
            key = name or SUBSYSTEM
            sizes[key] = sizes.get(key, 0) + size
            pos += 8 + nbytes
            if mtype != _MI_COMPRESSED:
                pos += -pos % 8
    return sizes


_MX_OPAQUE = 17  # a classdef object: flags, name, "MCOS", class name (no dimensions)


def _v5_matrix_header(buf: bytes, endian: str) -> tuple[str, int]:
    """(name, number of elements its dimensions declare) of a miMATRIX element's body."""
    out = []
    at = 0
    for _ in range(3):  # array flags, dimensions, name (an opaque object: flags, name)
        if at + 8 > len(buf):
            return "", 0
        word, nbytes = struct.unpack(endian + "II", buf[at:at + 8])
        if word >> 16:  # small data element: type and size in the first 4 bytes
            nbytes = word >> 16
            out.append(buf[at + 4:at + 4 + nbytes])
            at += 8
        else:
            out.append(buf[at + 8:at + 8 + nbytes])
            at += 8 + nbytes + (-nbytes % 8)
        if len(out) == 1 and len(out[0]) >= 4 and struct.unpack(endian + "I", out[0][:4])[0] & 0xFF == _MX_OPAQUE:
            out.append(b"")  # no dimensions: its data live in the class objects' store
    dims = struct.unpack(endian + "i" * (len(out[1]) // 4), out[1][: len(out[1]) // 4 * 4])
    count = 1
    for d in dims:
        count *= max(int(d), 0)
    return out[2].decode("ascii", "replace"), count


def _hdf5_sizes(path: Path) -> dict:
    import h5py

    limit = max_variable_bytes()
    sizes = {}
    try:
        with h5py.File(path, "r") as f:
            for name in f:
                if name == "#refs#":
                    continue
                key = SUBSYSTEM if name == "#subsystem#" else name
                sizes[key] = _hdf5_bytes(f[name], f, set(), limit)
    except (OSError, KeyError, ValueError) as exc:
        raise DataError([f"cannot read MATLAB -v7.3 (HDF5) file: {exc}"], source=str(path)) from exc
    return sizes


def _hdf5_bytes(obj, f, seen: set, limit: int) -> int:
    """Bytes an HDF5 object declares: a dataset's shape times its item size, plus what its
    MATLAB references (cells, structs, objects) point to; references are not followed past
    ``limit`` (the answer is then a lower bound, already too large)."""
    import h5py

    if isinstance(obj, h5py.Group):
        return sum(_hdf5_bytes(item, f, seen, limit) for item in obj.values())
    total = int(obj.size or 0) * obj.dtype.itemsize
    if total <= limit and h5py.check_dtype(ref=obj.dtype) is not None and obj.size:
        for ref in obj[()].ravel():
            if not ref:
                continue
            target = f[ref]
            if target.name in seen:
                continue
            seen.add(target.name)
            total += _hdf5_bytes(target, f, seen, limit)
            if total > limit:
                break
    return total


def _top_variable(name: str) -> str:
    """The file's variable a record or channel name lies in: ``data{2}`` -> ``data``,
    ``s.inner`` -> ``s``, ``io.posPert1`` -> ``io``."""
    return re.split(r"[.({]", name, maxsplit=1)[0]


def needed_variables(variable=None, channels=None) -> set | None:
    """The file's variables a read needs: a named variable (and the variables that channels
    named as ``VARIABLE.CHANNEL`` lie in); None when every variable may hold a channel.

    >>> sorted(needed_variables("z_df", {"scheduling": "sv.pos1"}))
    ['sv', 'z_df']
    >>> needed_variables() is None
    True
    """
    if variable is None or variable == TOP_LEVEL:
        return None
    names = {_top_variable(variable)}
    names |= {_top_variable(str(spec)) for spec in (channels or {}).values() if "." in str(spec)}
    return names


# --------------------------------------------------------------------------- reading


def read_mat(path, variables=None, skipped=None) -> list[Record]:
    """The records of a .mat file (see the module notes): of ``variables`` (top-level names)
    only, or of every variable. A variable over :func:`max_variable_bytes` is a DataError if
    it is one of ``variables`` (or class-object data), else skipped unread and its problem
    appended to ``skipped`` (a list). Raises DataError if the file cannot be read as a
    MATLAB file."""
    path = Path(path)
    limit = max_variable_bytes()
    sizes = declared_sizes(path)
    names = None if variables is None else sorted(variables)
    if sizes is not None:
        if names is not None and not set(names) <= set(sizes):  # a name not in the file (or in other
            names = None  # case): read what is there, so that the error lists it
        big = {k: v for k, v in sizes.items() if v > limit}
        for k, v in big.items():
            if k == SUBSYSTEM or (names is not None and k in names):  # needed: refused before reading
                raise DataError([over_limit(f"variable '{k}'", v, limit)], source=str(path))
        if names is None and big:
            names = [k for k in sizes if k not in big and k != SUBSYSTEM]
            if skipped is not None:
                skipped += [over_limit(f"variable '{k}' (not read)", v, limit) for k, v in big.items()]
    raw = _load(path, names)
    records: list[Record] = []
    top = Record(TOP_LEVEL, "variables")
    for name, value in raw.items():
        if name.startswith("__"):
            continue
        if _is_vector(value):
            top.channels[name] = _as_vector(value)
        elif _is_scalar(value) and name.lower() in RATE_FIELDS:
            _set_rate(top, name, value)
        else:
            try:
                records += _records(name, value)
            except DataError as exc:
                raise DataError(exc.problems, source=str(path)) from None
    if top.channels:
        records.insert(0, top)
    return records


def _load(path: Path, names=None) -> dict:
    if names is not None and not names:
        return {}
    try:
        with warnings.catch_warnings():  # mat-io sets a pandas option pandas 3 warns about
            warnings.simplefilter("ignore")
            import matio
    except ImportError as exc:  # mat-io needs Python 3.11: plain v5 files still read with scipy
        first = f"MATLAB class objects and v7.3 files need the mat-io package (Python >= 3.11): {exc}"
    else:
        try:
            return matio.load_from_mat(str(path), variable_names=None if names is None else list(names))
        except Exception as exc:  # mat-io raises many kinds; scipy may still read a plain v5 file
            first = f"{type(exc).__name__}: {exc}"
    try:
        import scipy.io

        return scipy.io.loadmat(str(path), variable_names=None if names is None else list(names))
    except Exception as exc:
        raise DataError([f"cannot read MATLAB file: {first}"], source=str(path)) from exc


def _is_numeric(x) -> bool:
    return isinstance(x, np.ndarray) and x.dtype.fields is None and (
        np.issubdtype(x.dtype, np.number) or x.dtype == bool) and not np.iscomplexobj(x)


def _is_vector(x) -> bool:
    return _is_numeric(x) and x.size >= 2 and x.size == max(x.shape)


def _is_scalar(x) -> bool:
    return _is_numeric(x) and x.size == 1


def _is_matrix(x) -> bool:
    return _is_numeric(x) and x.ndim == 2 and min(x.shape) > 1


def _as_vector(x) -> np.ndarray:
    return np.asarray(x, dtype=float).ravel()


def _set_rate(record: Record, name: str, value) -> None:
    v = float(np.asarray(value, dtype=float).ravel()[0])
    if np.isfinite(v) and v > 0:
        record.period = 1.0 / v if RATE_FIELDS[name.lower()] == "rate" else v


def _fields(value) -> dict | None:
    """Fields of a struct, a class object (classdef: its properties; old-style: its
    fields) or None if ``value`` is neither."""
    props = getattr(value, "properties", None)
    if isinstance(props, dict):
        return props
    if isinstance(value, np.ndarray) and value.dtype.fields is not None and value.size == 1:
        item = value.ravel()[0]
        return {k: item[k] for k in value.dtype.names}
    return None


def _class_name(value) -> str:
    return str(getattr(value, "classname", "") or "struct")


def _records(name: str, value) -> list[Record]:
    if isinstance(value, np.ndarray) and value.size > 1 and (value.dtype == object or value.dtype.fields):
        # cells (name{k}) and arrays of objects or structs (name(k)), e.g. several nldat trials
        open_, close = ("(", ")") if getattr(value, "classname", None) or value.dtype.fields else ("{", "}")
        items = value.ravel(order="F")
        out = []
        for k in range(items.size):
            item = items[k] if value.dtype.fields is None else items[k : k + 1]
            out += [_matrix(f"{name}{open_}{k + 1}{close}", item)] if _is_matrix(item) else \
                _records(f"{name}{open_}{k + 1}{close}", item)
        return out
    fields = _fields(value)
    if fields is not None:
        if "dataSet" in fields:
            return [_nldat(name, fields, _class_name(value))]
        rec = Record(name, _class_name(value))
        nested = []
        for key, v in fields.items():
            if _is_vector(v):
                rec.channels[key] = _as_vector(v)
            elif _is_scalar(v) and key.lower() in RATE_FIELDS:
                _set_rate(rec, key, v)
            elif _is_matrix(v):
                nested.append(_matrix(f"{name}.{key}", v))
            else:
                nested += _records(f"{name}.{key}", v)
        return ([rec] if rec.channels else []) + nested
    if _is_matrix(value):
        return [_matrix(name, value)]
    return []  # text, cells, function handles, empty arrays: nothing to read


def _matrix(name: str, value) -> Record:
    x = np.asarray(value, dtype=float)
    if x.shape[0] < x.shape[1]:  # channels in rows (MATLAB users store both ways)
        x = x.T
    return Record(name, "matrix", {str(j + 1): x[:, j].copy() for j in range(x.shape[1])})


def _strings(value) -> list[str]:
    """Every string in a (nested) MATLAB char/cell/string array, in order."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, bytes):
        return [value.decode("utf-8", "replace")]
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "US":  # char arrays arrive as arrays of whole strings
            return [_strings(s)[0] for s in value.ravel().tolist()]
        if value.dtype == object:
            out = []
            for item in value.ravel(order="F"):
                out += _strings(item)
            return out
    return []


def _nldat(name: str, fields: dict, kind: str) -> Record:
    data = np.asarray(fields["dataSet"])
    rec = Record(name, kind)
    if not _is_numeric(data) or data.size == 0:
        return rec
    if data.ndim == 3 and data.shape[2] == 1:
        data = data[:, :, 0]
    if data.ndim == 1:
        data = data[:, None]
    if data.ndim != 2:
        raise DataError([f"variable '{name}': dataSet of shape {data.shape} (several realizations) is not "
                         f"supported; save one realization per variable"])
    names = _strings(fields.get("chanNames"))
    if len(names) != data.shape[1] or len(set(names)) != len(names):
        names = [str(j + 1) for j in range(data.shape[1])]
    rec.channels = {c: np.asarray(data[:, j], dtype=float) for j, c in enumerate(names)}
    incr = np.asarray(fields.get("domainIncr", np.nan), dtype=float).ravel()
    if incr.size == 1 and np.isfinite(incr[0]) and incr[0] > 0:
        rec.period = float(incr[0])
    start = np.asarray(fields.get("domainStart", 0.0), dtype=float).ravel()
    rec.start = float(start[0]) if start.size == 1 and np.isfinite(start[0]) else 0.0
    values = np.asarray(fields.get("domainValues", np.nan), dtype=float).ravel()
    if values.size == data.shape[0] and np.all(np.isfinite(values)):  # unevenly sampled nldat
        rec.time = values
    return rec


# --------------------------------------------------------------------------- choosing channels


def found(records) -> str:
    """One-line summary of the variables and channels of a file.

    >>> found([Record("z_df", "nldat", {"pos1": np.zeros(2), "tq1": np.zeros(2)}, period=0.001)])
    'z_df (nldat, 2 samples at 1000 Hz: pos1, tq1)'
    """
    return "; ".join(r.describe() for r in records) or "nothing readable (no numeric vectors, matrices or nldat objects)"


def _match(records, spec: str, source: str, role: str):
    """(record, channel) named by ``spec``: a channel name (a matrix's columns are named
    ``1``, ``2``, ...), ``variable.channel``, or a variable holding one channel."""
    spec_l = spec.strip().lower()
    hits = [(r, c) for r in records for c in r.channels if c.lower() == spec_l]
    if not hits:
        for r in records:
            for c in r.channels:
                if f"{r.name}.{c}".lower() == spec_l:
                    hits.append((r, c))
    if not hits:
        hits = [(r, next(iter(r.channels))) for r in records if r.name.lower() == spec_l and len(r.channels) == 1]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        raise DataError([f"no channel '{spec}' for {role} (found: {found(records)})"], source=source)
    where = ", ".join(f"{r.name}.{c}" for r, c in hits)
    raise DataError([f"channel '{spec}' for {role} is in several variables ({where}); name it as "
                     f"VARIABLE.CHANNEL or choose the variable"], source=source)


def _candidates(records, role, used):
    names = ROLE_NAMES.get(role, ())
    exact = [(r, c) for r in records for c in r.channels if c.lower() in names and (r.name, c) not in used]
    if exact or role not in ROLE_PATTERNS:
        return exact
    pats = ROLE_PATTERNS[role]
    return [(r, c) for r in records for c in r.channels
            if (r.name, c) not in used and any(p in c.lower() for p in pats)]


def _scheduling_candidates(records, used, home):
    hits = _candidates(records, "scheduling", used)
    if hits:
        return hits
    hits = [(r, c) for r in records for c in r.channels if (r.name, c) not in used
            and r.name.lower().split(".")[-1] in SCHEDULING_RECORDS
            and (len(r.channels) == 1 or any(p in c.lower() for p in ROLE_PATTERNS["position"]))]
    if hits:
        return hits
    # The lab's files: the perturbation and the scheduling position sit in different variables.
    return [(r, c) for r, c in _candidates(records, "position", used) if home is not None and r is not home]


def select_channels(records, required, optional=(), *, channels=None, variable=None, source="") -> dict:
    """Choose the channels of each role and return them as ``{role: array}`` (``time`` in s
    from a time channel or from the variable's sample period).

    ``required``/``optional``: roles such as "time", "position", "torque", "scheduling",
    "emg", "command". ``channels`` maps roles to channel names (``"pos1"``,
    ``"io.posPert1"``, a column number ``"2"``); ``variable`` restricts the search to one
    variable (record) of the file. Roles not named are found automatically: an exact name
    (``position``, ``torque``, ...), else a unique name containing ``pos``/``angle``
    (position), ``tq``/``torque`` (torque), ``sched``/``rho`` (scheduling; in the lab's
    files the position channel of another variable, e.g. ``sv``); optional roles only by
    their exact name. Torque is chosen first; position and the optional channels are
    preferred from the same variable. Raises DataError (one line, listing what was found)
    when a required channel is missing or a choice is ambiguous.

    Roles found by name: torque from ``tq1``, position from ``pos1`` of the same variable,
    time from its sample period (s):

    >>> r = Record("z_df", "nldat", {"pos1": np.zeros(4), "tq1": np.arange(4.0)}, period=0.001)
    >>> chans = select_channels([r], ["time", "position", "torque"])
    >>> chans["torque"], chans["time"]
    (array([0., 1., 2., 3.]), array([0.   , 0.001, 0.002, 0.003]))
    """
    channels = dict(channels or {})
    unknown = sorted(set(channels) - set(required) - set(optional))
    if unknown:
        raise DataError([f"unknown channel role(s) {', '.join(unknown)} (roles: {', '.join((*required, *optional))})"],
                        source=source)
    if not any(r.channels for r in records):
        raise DataError([f"no usable channel: the file holds {found(records)}"], source=source)
    pool = records
    if variable is not None:
        pool = [r for r in records if r.name == variable] or [r for r in records if r.name.lower() == variable.lower()]
        if len(pool) != 1:
            raise DataError([f"no variable '{variable}' with channels (found: {found(records)})"], source=source)
    chosen: dict[str, tuple] = {}
    used: set = set()
    for role, spec in channels.items():
        rec, c = _match(pool if variable is not None and "." not in str(spec) else records, str(spec), source, role)
        chosen[role] = (rec, c)
        used.add((rec.name, c))
    order = [r for r in ("torque", "position", "scheduling", "time") if r in required or r in optional]
    order += [r for r in (*required, *optional) if r not in order]
    for role in order:
        if role in chosen:
            continue
        home = chosen.get("torque", chosen.get("position", (None,)))[0]
        if role not in required:  # optional channels only by their exact name: no guessing
            hits = [h for h in _candidates(pool, role, used) if h[1].lower() in ROLE_NAMES.get(role, ())]
        elif role == "scheduling":
            hits = _scheduling_candidates(pool, used, home)
        else:
            hits = _candidates(pool, role, used)
        if role == "time" and home is not None and home.times() is not None:
            hits = [h for h in hits if h[0] is home]  # the chosen variable's own time axis
        if len(hits) > 1 and home is not None:
            mine = [h for h in hits if h[0] is home]
            hits = mine or hits
        if role == "time" and not hits:
            continue  # from the record's sample period below
        if len(hits) == 1:
            chosen[role] = hits[0]
            used.add((hits[0][0].name, hits[0][1]))
        elif role in required:
            raise DataError([_choice_problem(role, hits, pool, variable)], source=source)
        # an optional channel that is absent or ambiguous is not read
    return _assemble(chosen, required, source, records)


def _choice_problem(role, hits, pool, variable) -> str:
    if not hits:
        what = f"in variable '{variable}'" if variable else "in the file"
        also = ("; or, for a trial around one fixed position recorded without UT, read it as stationary "
                "(stationary=True, --stationary)" if role == "scheduling" else "")
        return (f"no {role} channel found {what} (found: {found(pool)}); name it with "
                f"channels={{'{role}': NAME}} (--channel {role}=NAME){also}")
    records = {h[0].name for h in hits}
    listed = ", ".join(f"{r.name}.{c}" if r.name != TOP_LEVEL else c for r, c in hits)
    hint = ("choose the variable with variable=NAME (--variable NAME)" if len(records) > 1 and variable is None
            else f"name it with channels={{'{role}': NAME}} (--channel {role}=NAME)")
    return f"ambiguous {role} channel: {listed}; {hint} (found: {found(pool)})"


def _assemble(chosen, required, source, records) -> dict:
    table = {role: rec.channels[c] for role, (rec, c) in chosen.items()}
    used_records = {id(rec): rec for rec, _ in chosen.values()}.values()
    if "time" in required and "time" not in table:
        domains = [rec for rec in used_records if rec.times() is not None]
        if not domains:
            raise DataError([f"no time: no 'time' channel and no sample period in "
                             f"{', '.join(r.name for r in used_records)} (found: {found(records)})"], source=source)
        table["time"] = domains[0].times()
    # Channels taken from different variables must describe the same samples.
    periods = {rec.name: rec.period for rec in used_records if rec.period}
    if periods and max(periods.values()) > min(periods.values()) * (1 + 1e-9):
        listed = ", ".join(f"{k} {1 / v:.6g} Hz" for k, v in periods.items())
        raise DataError([f"the chosen variables differ in sampling rate: {listed}"], source=source)
    return table


def parse_channel_options(items) -> dict:
    """``["position=pos1", "torque=io.tqPert1"]`` -> ``{"position": "pos1", ...}`` (the
    CLI's repeated ``--channel ROLE=NAME``). Raises ValueError naming a malformed item.

    >>> parse_channel_options(["position=pos1", "torque = io.tqPert1"])
    {'position': 'pos1', 'torque': 'io.tqPert1'}
    >>> parse_channel_options(["position"])
    Traceback (most recent call last):
    ...
    ValueError: expected ROLE=NAME, got 'position'
    """
    out = {}
    for item in items or ():
        role, sep, name = str(item).partition("=")
        role = role.strip().lower()
        if not sep or not role or not name.strip():
            raise ValueError(f"expected ROLE=NAME, got {item!r}")
        if role in out:
            raise ValueError(f"channel role '{role}' given twice")
        out[role] = name.strip()
    return out


def is_mat(path) -> bool:
    """True for a MATLAB file name (``.mat``, any case).

    >>> is_mat("PilotData.MAT"), is_mat("PT.csv")
    (True, False)
    """
    return Path(path).suffix.lower() == ".mat"


def split_variable(path) -> tuple[Path, str | None]:
    """``"file.mat:NAME"`` -> (``file.mat``, ``"NAME"``): a variable named with the path
    (e.g. ``--pt experimental_data.mat:z_df``); other paths -> (path, None).

    Parameters
    ----------
    path : str or pathlib.Path
        The path, with or without a variable name.

    Returns
    -------
    tuple
        ``(pathlib.Path, str or None)``: the file and the variable's name.

    Examples
    --------
    >>> split_variable("experimental_data.mat:z_df")
    (PosixPath('experimental_data.mat'), 'z_df')
    >>> split_variable("PT.csv")
    (PosixPath('PT.csv'), None)
    """
    text = str(path)
    head, sep, name = text.rpartition(":")
    if sep and head.lower().endswith(".mat") and name and "/" not in name and "\\" not in name \
            and not Path(text).exists():
        return Path(head), name
    return Path(path), None
