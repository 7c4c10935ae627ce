"""Outputs: never over an input, written whole or not at all, with the user's permissions.

- :func:`check_outputs` refuses an output path that is one of the command's inputs (or
  would overwrite one through a sidecar), compared as files (``samefile``: symlinks and
  hard links) or resolved paths; and an input inside an output folder that is replaced
  as a whole.
- :func:`atomic_path` / :func:`write_text` / :func:`write_bytes` write to a temporary file in
  the target folder and rename it over the target: a reader sees the old file or the new
  one, never half of one; an exception, Ctrl-C or SIGTERM (which the command line turns
  into the same :class:`KeyboardInterrupt` path) removes the temporary file.
- :func:`staged_folder` builds an output folder beside its target and swaps it in at the
  end, so a folder never mixes two runs and a failed run leaves the previous one intact.
- Every output gets the mode a plain ``open()`` would give it: 0666 (folders 0777) less
  the umask (``mkstemp`` alone gives 0600).
"""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
from contextlib import contextmanager
from pathlib import Path

from .errors import LpvpcError

TEMP_SUFFIX = ".lpvpc-tmp"  # temporary outputs: ".<name>.<random>.lpvpc-tmp" beside the target


class OutputPathError(LpvpcError):
    """An output path would overwrite an input (or another output of the same command).

    >>> check_outputs({"--pt": "PT.csv"}, {"--out": "PT.csv"})
    Traceback (most recent call last):
    ...
    lpvpc.outputs.OutputPathError: ...
    """

    exit_status = 2


# --------------------------------------------------------------------------- path checks
def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one does not exist (yet): compare where the paths lead
        return os.path.realpath(a) == os.path.realpath(b)


def _inside(path, folder) -> bool:
    p, f = os.path.realpath(path), os.path.realpath(folder)
    return p == f or p.startswith(f.rstrip(os.sep) + os.sep) or _same_file(path, folder)


def check_outputs(inputs: dict, outputs: dict, folders: dict | None = None) -> None:
    """Raise :class:`OutputPathError` if an output would replace an input.

    ``inputs``, ``outputs``, ``folders``: {label: path or None} (labels name the option,
    e.g. ``"--pt"``, ``"--casadi sidecar"``). ``outputs`` are files the command writes;
    ``folders`` are output folders it replaces as a whole (no input may lie inside one).
    Two outputs that are the same file are refused as well.

    >>> check_outputs({"--pt": "PT.csv"}, {"-o": "model.json"})  # fine: returns None
    >>> check_outputs({"--pt": "run/PT.csv"}, {}, {"--report": "run"})
    Traceback (most recent call last):
    ...
    lpvpc.outputs.OutputPathError: ...
    """
    ins = [(k, v) for k, v in inputs.items() if v is not None]
    outs = [(k, v) for k, v in outputs.items() if v is not None]
    for out_label, out in outs:
        for in_label, inp in ins:
            if _same_file(out, inp):
                raise OutputPathError(f"output {out_label} {out} is the input {in_label} {inp}: refusing to overwrite "
                                      "it (choose another output path)")
    for i, (a_label, a) in enumerate(outs):
        for b_label, b in outs[i + 1:]:
            if _same_file(a, b):
                raise OutputPathError(f"outputs {a_label} {a} and {b_label} {b} are the same file")
    for f_label, folder in (folders or {}).items():
        if folder is None:
            continue
        for in_label, inp in ins:
            if _inside(inp, folder):
                raise OutputPathError(f"input {in_label} {inp} lies inside the output folder {f_label} {folder}, "
                                      "which is replaced as a whole: move the input or choose another folder")


# --------------------------------------------------------------------------- permissions
def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a new output file: 0666 less the umask (what ``open()`` gives).

    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     made = Path(tmp) / "by_open.txt"
    ...     _ = made.write_text("")
    ...     print(made.stat().st_mode & 0o777 == file_mode())
    True
    """
    return 0o666 & ~_umask()


def folder_mode() -> int:
    """Mode of a new output folder: 0777 less the umask (what ``mkdir`` gives).

    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     (Path(tmp) / "made").mkdir()
    ...     print((Path(tmp) / "made").stat().st_mode & 0o777 == folder_mode())
    True
    """
    return 0o777 & ~_umask()


# --------------------------------------------------------------------------- atomic files
@contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; on success it is renamed over ``path``
    (mode :func:`file_mode`), on any exception (also KeyboardInterrupt) removed.

    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     target = Path(tmp) / "model.json"
    ...     with atomic_path(target) as partial:
    ...         _ = partial.write_text("{}")
    ...         print(target.exists())  # nothing at the target until the block succeeds
    ...     print(target.read_text())
    False
    {}
    """
    path = Path(path)
    tmp = None
    try:
        with signals_held():  # no signal between creating the file and owning it
            fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
            tmp = Path(name)
            os.close(fd)
        yield tmp
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise


def write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (:func:`atomic_path`): readers see the old file or
    the whole new one, never a part; returns the path.

    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     print(write_text(Path(tmp) / "a.txt", "done").read_text())
    done
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding=encoding)
    return Path(path)


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`): readers see the old file or
    the whole new one, never a part; returns the path.

    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     print(write_bytes(Path(tmp) / "a.bin", bytes([0, 1])).stat().st_size)
    2
    """
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


# --------------------------------------------------------------------------- folders
@contextmanager
def signals_held():
    """Hold SIGINT and SIGTERM over a few renames (delivered right after).

    >>> with signals_held():  # Ctrl-C waits until the block ends
    ...     pass
    """
    held = {signal.SIGINT, signal.SIGTERM}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    except (AttributeError, ValueError, OSError):  # not the main thread / no pthreads
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


@contextmanager
def staged_folder(folder):
    """Yield an empty folder beside ``folder``; on success it replaces ``folder`` (any
    previous content goes), on any exception it is removed and ``folder`` is untouched.

    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     report = Path(tmp) / "report"
    ...     with staged_folder(report) as stage:
    ...         _ = (stage / "index.html").write_text("<html></html>")
    ...     print(sorted(p.name for p in report.iterdir()))
    ['index.html']
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(20, "not a folder", str(folder))
    parent = folder.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    stage = None
    try:
        with signals_held():  # no signal between creating the folder and owning it
            stage = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=TEMP_SUFFIX, dir=parent))
        os.chmod(stage, folder_mode())
        yield stage
    except BaseException:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
        raise
    old = None
    with signals_held():
        if folder.is_dir():
            old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.old.", suffix=TEMP_SUFFIX, dir=parent))
            os.rmdir(old)
            os.rename(folder, old)
        os.rename(stage, folder)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
