"""Outputs: never over an input, written whole or not at all, with the user's permissions.

- :class:`CommandIO` is the one output policy of the command line: each command declares
  the options it reads and writes, and :meth:`CommandIO.check` refuses, before any work, an
  output that is, links to or contains an input, or that cannot be written (missing or
  read-only folder, a folder where a file is expected), naming the user's paths.
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
  the umask (``mkstemp`` alone gives 0600); a file that is replaced keeps its own mode (and
  owner where permitted): a private 0600 model stays 0600.
- A FIFO, a device or a path under /dev (``/dev/stdout``) is written into directly, never
  replaced by a rename.
- :func:`check_model_output` refuses to write a model over an existing file that is not a
  model file of ours (a recording given as ``-o`` by mistake) unless ``--force``: every
  command that saves a model declares that output in :attr:`CommandIO.models`.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import stat
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import LpvpcError

TEMP_SUFFIX = ".lpvpc-tmp"  # temporary outputs: ".<name>.<random>.lpvpc-tmp" beside the target


class OutputPathError(LpvpcError):
    """An output path would overwrite an input (or another output of the same command).

    >>> check_outputs({"--pt": "PT.csv"}, {"--out": "PT.csv"})
    Traceback (most recent call last):
    ...
    lpvpc.io.outputs.OutputPathError: ...
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
    Two outputs that are the same file are refused as well, and an output file inside an
    output folder (the folder's swap would delete it).

    >>> check_outputs({"--pt": "PT.csv"}, {"-o": "model.json"})  # fine: returns None
    >>> check_outputs({"--pt": "run/PT.csv"}, {}, {"--report": "run"})
    Traceback (most recent call last):
    ...
    lpvpc.io.outputs.OutputPathError: ...
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
            if _same_file(a, b) and not is_special(a):  # two outputs into one stream (/dev/null): fine
                raise OutputPathError(f"outputs {a_label} {a} and {b_label} {b} are the same file")
    for f_label, folder in (folders or {}).items():
        if folder is None:
            continue
        for in_label, inp in ins:
            if _inside(inp, folder):
                raise OutputPathError(f"input {in_label} {inp} lies inside the output folder {f_label} {folder}, "
                                      "which is replaced as a whole: move the input or choose another folder")
        for out_label, out in outs:
            if _inside(out, folder):
                raise OutputPathError(f"output {out_label} {out} lies inside the output folder {f_label} {folder}, "
                                      "which is replaced as a whole: choose a path outside it")


# --------------------------------------------------------------------------- the policy
@dataclass(frozen=True)
class CommandIO:
    """What one command reads and writes: {option label: argparse dest}.

    ``inputs``: files the command reads (a value may be a list; ``file.mat:VARIABLE`` is the
    file ``file.mat``); ``files``: files it writes; ``folders``: folders it replaces as a
    whole; ``sidecars``: {file label: suffixes of files written beside it}
    (``--casadi F`` also writes ``F.json``); ``regular``: file outputs that must be regular
    files (an FMU is built beside its target, a CasADi function has a sidecar beside it: they
    cannot go to a FIFO or device);
    ``make_folders``: file outputs whose missing folders the command creates (an FMU's);
    ``models``: file outputs that hold a model, which may replace only a model file of ours
    (:func:`check_model_output`; ``args.force`` replaces any file).

    >>> io = CommandIO(inputs={"--pt": "pt"}, files={"-o": "output"})
    >>> from argparse import Namespace
    >>> io.check(Namespace(pt="PT.csv", output="model.json"))  # fine: returns None
    >>> io.check(Namespace(pt="PT.csv", output="PT.csv"))
    Traceback (most recent call last):
    ...
    lpvpc.io.outputs.OutputPathError: output -o PT.csv is the input --pt PT.csv: refusing to overwrite it (choose another output path)
    """

    inputs: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)
    folders: dict = field(default_factory=dict)
    sidecars: dict = field(default_factory=dict)
    regular: tuple = ()
    make_folders: tuple = ()
    models: tuple = ()

    def resolve(self, args):
        """(inputs, files, folders) as {label: path} from the parsed ``args``, every file
        an input names (several trials: every one) and every sidecar included."""
        ins = {}
        for label, dest in self.inputs.items():
            for i, value in enumerate(_values(getattr(args, dest, None))):
                ins[label if i == 0 else f"{label} #{i + 1}"] = str(input_file(value))
        files = {}
        for label, dest in self.files.items():
            for value in _values(getattr(args, dest, None)):
                files[label] = str(value)
                for suffix in self.sidecars.get(label, ()):
                    files[f"{label} sidecar"] = str(value) + suffix
        folders = {label: str(v) for label, dest in self.folders.items() for v in _values(getattr(args, dest, None))}
        return ins, files, folders

    def check(self, args) -> None:
        """Refuse (OutputPathError, one line naming both paths) an output that is, links to
        or contains an input, and an output that cannot be written (missing or read-only
        folder, a folder where a file is expected): before any work."""
        ins, files, folders = self.resolve(args)
        check_outputs(ins, files, folders)
        for label, path in files.items():
            option = label.split(" ")[0]
            check_writable_file(label, path, regular=option in self.regular, make_folders=option in self.make_folders)
            if label in self.models:
                check_model_output(label, path, force=bool(getattr(args, "force", False)))
        for label, path in folders.items():
            check_writable_folder(label, path)


def _values(value) -> list:
    return [] if value is None else list(value) if isinstance(value, (list, tuple)) else [value]


def input_file(value) -> Path:
    """The file an input names: ``file.mat:VARIABLE`` is ``file.mat`` (the rule of
    :func:`lpvpc.io.matfiles.split_variable`), anything else the path itself.

    >>> str(input_file("s.mat:pt")), str(input_file("PT.csv"))
    ('s.mat', 'PT.csv')
    """
    from .matfiles import split_variable

    return split_variable(value)[0]


# Paths that name an open descriptor: a file they reach (``/dev/stdout`` redirected to a log)
# is written into, not replaced (a rename would replace the link in /dev).
DESCRIPTOR_PATHS = ("/dev/stdin", "/dev/stdout", "/dev/stderr", "/dev/fd/", "/proc/")


def is_special(path) -> bool:
    """True for an existing path that is not a regular file or folder (a FIFO, a device, a
    socket), or names an open descriptor (``/dev/stdout``, ``/dev/fd/N``, ``/proc/...``,
    also when it reaches a regular file): such a path is written into directly, never
    replaced by a rename. A regular file elsewhere (``/dev/shm/x.json`` too) is not special.

    >>> is_special("/dev/null"), is_special("/nonexistent/x.json")
    (True, False)
    """
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    if stat.S_ISDIR(mode):
        return False
    absolute = os.path.abspath(path)
    return not stat.S_ISREG(mode) or absolute.startswith(DESCRIPTOR_PATHS)


def check_writable_file(label, path, *, regular: bool = False, make_folders: bool = False) -> None:
    """Raise OutputPathError (naming the user's path) unless ``path`` can be written: not a
    folder, its folder exists (``make_folders``: the nearest existing folder above it) and is
    writable, an existing file is not read-only; a FIFO or device is written into directly
    (refused when ``regular``).

    >>> check_writable_file("-o", "/nonexistent-folder/model.json")
    Traceback (most recent call last):
    ...
    lpvpc.io.outputs.OutputPathError: output -o /nonexistent-folder/model.json: folder /nonexistent-folder does not exist
    """
    p = Path(path)
    if p.is_dir():
        raise OutputPathError(f"output {label} {path} is a folder: give a file name")
    if is_special(p):
        if regular:
            raise OutputPathError(f"output {label} {path} is not a regular file (a FIFO, device or /dev path): "
                                  "write it to a file")
        if not os.access(p, os.W_OK):
            raise OutputPathError(f"output {label} {path} is not writable")
        return
    folder = p.absolute().parent
    while make_folders and not folder.exists():
        folder = folder.parent
    if not folder.exists():
        raise OutputPathError(f"output {label} {path}: folder {folder} does not exist")
    if not folder.is_dir():
        raise OutputPathError(f"output {label} {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"output {label} {path}: folder {folder} is not writable")
    if p.is_file() and not os.access(p, os.W_OK):
        raise OutputPathError(f"output {label} {path} is read-only: refusing to replace it")


# What a model file of ours starts with: its first key (lpvpc.models.model, lpvpc.export.whole_joint).
MODEL_FORMATS = ("lpvpc-model", "lpvpc-whole-joint")
_FORMAT_KEY = re.compile(rb'^\s*\{\s*"format"\s*:\s*"([^"]*)"')


def is_model_file(path) -> bool:
    """True when ``path`` starts like a model file of ours (JSON whose first key is
    ``"format"`` with a value in :data:`MODEL_FORMATS`); only its first bytes are read.

    >>> import json, tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> _ = (d / "m.json").write_text(json.dumps({"format": MODEL_FORMATS[0]}))
    >>> _ = (d / "r.csv").write_text("time,position,torque")
    >>> is_model_file(d / "m.json"), is_model_file(d / "r.csv")
    (True, False)
    """
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    m = _FORMAT_KEY.match(head)
    return bool(m) and m.group(1).decode("utf-8", "replace") in MODEL_FORMATS


def check_model_output(label, path, force: bool = False) -> None:
    """Raise OutputPathError when the model output ``path`` exists as a non-empty regular
    file that is not a model file of ours (a recording or another program's file given as
    ``-o`` by mistake), unless ``force``: a model replaces only a model.

    >>> import tempfile, pathlib
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     rec = pathlib.Path(tmp) / "PT.csv"
    ...     _ = rec.write_text("time,position,torque\\n0,0,0\\n")
    ...     check_model_output("-o", rec)
    Traceback (most recent call last):
    ...
    lpvpc.io.outputs.OutputPathError: ...
    """
    p = Path(path)
    if force or is_special(p) or not p.is_file() or p.stat().st_size == 0 or is_model_file(p):
        return
    raise OutputPathError(f"output {label} {path} exists and is not an lpvpc model file: refusing to replace it "
                          "(give another path, or --force to replace it)")


def check_writable_folder(label, path) -> None:
    """Raise OutputPathError unless the output folder ``path`` can be (re)built: not a file,
    and the nearest existing folder above it is writable (missing folders are created).

    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     check_writable_folder("--report", Path(tmp) / "new" / "report")  # created later: fine
    ...     _ = (Path(tmp) / "notes.txt").write_text("")
    ...     check_writable_folder("--report", Path(tmp) / "notes.txt")
    Traceback (most recent call last):
    ...
    lpvpc.io.outputs.OutputPathError: output folder --report ... is a file: give a folder
    """
    p = Path(path).absolute()
    if p.exists() and not p.is_dir():
        raise OutputPathError(f"output folder {label} {path} is a file: give a folder")
    above = p.parent
    while not above.exists():
        above = above.parent
    if not above.is_dir():
        raise OutputPathError(f"output folder {label} {path}: {above} is not a folder")
    if not os.access(above, os.W_OK | os.X_OK):
        raise OutputPathError(f"output folder {label} {path}: folder {above} is not writable")


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
    """Yield a temporary path beside ``path``; on success it is renamed over ``path``, on any
    exception (also KeyboardInterrupt) removed. A new file gets :func:`file_mode`, a replaced
    one keeps its mode (and owner where permitted). A FIFO, device or /dev path
    (:func:`is_special`) is not replaced: the finished temporary file (in the system's
    temporary folder) is written into it.

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
    if path.is_dir():
        raise IsADirectoryError(21, "is a folder, not a file", str(path))
    special = is_special(path)
    tmp = None
    try:
        with signals_held():  # no signal between creating the file and owning it
            fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX,
                                        dir=None if special else path.parent)
            tmp = Path(name)
            os.close(fd)
        yield tmp
        if special:
            _write_into(tmp, path)
            tmp.unlink()
            return
        _copy_owner_and_mode(path, tmp)
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise


def _copy_owner_and_mode(target: Path, tmp: Path) -> None:
    """The mode (and owner, group where permitted) of the file being replaced, else the
    mode a plain ``open()`` would give."""
    try:
        st = os.stat(target)
    except OSError:
        os.chmod(tmp, file_mode())
        return
    if (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
        try:
            os.chown(tmp, st.st_uid, st.st_gid)
        except OSError:  # not permitted (another user's file): the mode still follows
            pass
    os.chmod(tmp, st.st_mode & 0o777)  # permission bits only: no set-id bit carried to new content


def _write_into(tmp: Path, target: Path) -> None:
    """Copy the finished ``tmp`` into a FIFO, device or /dev path: our own stdout/stderr
    through their descriptors (after what was printed), anything else opened for writing
    (appending, never created or truncated)."""
    st = os.stat(target)
    for stream in (sys.stdout, sys.stderr):
        try:
            fd = stream.fileno()
            same = os.path.samestat(st, os.fstat(fd))
        except (AttributeError, OSError, ValueError):  # replaced streams (pytest's capture)
            continue
        if same:
            stream.flush()
            with open(tmp, "rb") as src:
                while chunk := src.read(1 << 16):
                    view = memoryview(chunk)
                    while view:
                        view = view[os.write(fd, view):]
            return
    fd = os.open(target, os.O_WRONLY | os.O_APPEND)
    with os.fdopen(fd, "wb") as dst, open(tmp, "rb") as src:
        shutil.copyfileobj(src, dst)


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
