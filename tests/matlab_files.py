"""Writers of small MATLAB files in the lab's format, for the loader tests.

``nldat`` objects are written as MATLAB class objects by ``mat-io`` (classdef/MCOS objects,
as in the lab's files, or old-style class objects), in v7 or v7.3 format, with the fields
the lab's files carry (``dataSet`` N x channels, ``chanNames``, ``chanUnits``,
``domainIncr`` (s), ``domainStart`` (s), ``domainValues`` NaN, ``domainName``, ``comment``).
Plain -v7.3 files are also written directly with h5py from the MAT-file layout (a 512-byte
user block with MATLAB's header, one HDF5 dataset per variable, stored transposed, with a
``MATLAB_class`` attribute), independently of mat-io's writer.
"""

from __future__ import annotations

import warnings

import numpy as np


def _cellstr(names):
    cell = np.empty((1, len(names)), dtype=object)
    for j, n in enumerate(names):
        cell[0, j] = np.array([n])
    return cell


def nldat_fields(data, names, period, start=0.0):
    data = np.asarray(data, dtype=float)
    return {
        "chanNames": _cellstr(names),
        "chanUnits": _cellstr(["Default Units"]),
        "comment": np.array(["test object"]),
        "dataSet": data,
        "dataSize": np.array([[float(data.shape[0]), float(data.shape[1])]]),
        "domainIncr": np.array([[float(period)]]),
        "domainName": np.array(["Time (s)"]),
        "domainStart": np.array([[float(start)]]),
        "domainValues": np.array([[np.nan]]),
        "version": np.array(["2.01"]),
    }


def _matio():
    with warnings.catch_warnings():  # mat-io sets a pandas option pandas 3 warns about
        warnings.simplefilter("ignore")
        import matio
        import matio.utils.matclass
    return matio


def nldat(data, names, period, start=0.0, style="classdef"):
    """An nldat object: ``style`` "classdef" (MCOS, like the lab's files) or "oldstyle"."""
    matclass = _matio().utils.matclass
    MatlabObject, MatlabOpaque = matclass.MatlabObject, matclass.MatlabOpaque

    fields = nldat_fields(data, names, period, start)
    if style == "classdef":
        return MatlabOpaque(fields, "nldat")
    rec = np.empty((1, 1), dtype=[(k, "O") for k in fields])
    for k, v in fields.items():
        rec[0, 0][k] = v
    return MatlabObject(rec, classname="nldat")


def write_mat(path, variables: dict, version="v7"):
    """Write ``variables`` (arrays, dicts as structs, nldat objects) with mat-io."""
    _matio().save_to_mat(str(path), variables, version=version)
    return path


def write_v73_plain(path, variables: dict):
    """A -v7.3 (HDF5) MAT-file of real double arrays, written with h5py from the format's
    layout: MATLAB's 128-byte header in a 512-byte user block, datasets column-major."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            x = np.atleast_2d(np.asarray(value, dtype=float))
            ds = f.create_dataset(name, data=x.T)  # MATLAB stores column-major: HDF5 sees the transpose
            ds.attrs["MATLAB_class"] = np.bytes_("double")
    text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    header = text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    with open(path, "r+b") as f:
        f.write(header)
    return path
