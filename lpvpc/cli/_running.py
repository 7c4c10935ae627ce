"""Running a command: library warnings and notes as one-line messages, progress lines with
the elapsed time, and SIGTERM taking the Ctrl-C path."""

from __future__ import annotations

import signal
import sys
import time

from ..errors import LpvpcWarning
from ..report_html import command_line_syntax
from ._common import PROG, _one_line


def _show_warning(original):
    """A ``warnings.showwarning`` that prints the package's warnings as one line each, and each
    text once: a command that fits several models (improve, validate) met the same note about
    every one of them, three times in a row on one step."""
    shown = set()

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, LpvpcWarning):
            text = f"{PROG}: warning: {_one_line(command_line_syntax(message))}"
            if text not in shown:
                shown.add(text)
                print(text, file=sys.stderr)
        else:
            original(message, category, filename, lineno, file, line)

    return show


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that it takes the same clean-up path as
    Ctrl-C (temporary files and folders removed, the compiler killed)."""


def _raise_terminated(signum, frame):
    raise Terminated()


def _terminate_as_interrupt():
    """Install the SIGTERM handler (main thread only); returns the previous one."""
    try:
        return signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread
        return None


def _show_notes() -> None:
    """--verbose: the library's notes (logging, INFO) as lines ``lpvpc: note: ...`` on stderr."""
    import logging

    logger = logging.getLogger("lpvpc")
    if any(getattr(h, "lpvpc_notes", False) for h in logger.handlers):
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{PROG}: note: %(message)s"))
    handler.lpvpc_notes = True
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)


class _ProgressLines:
    """The library's progress (:mod:`lpvpc.progress`) as lines ``lpvpc: [  3.1 s] ...`` on
    stderr while a command runs (seconds since it started)."""

    def __enter__(self):
        import logging

        start = time.perf_counter()

        class Elapsed(logging.Formatter):
            def format(self, record):
                return f"{PROG}: [{time.perf_counter() - start:5.1f} s] {record.getMessage()}"

        self.logger = logging.getLogger("lpvpc.progress")
        self.level = self.logger.level
        self.handler = logging.StreamHandler(sys.stderr)
        self.handler.setFormatter(Elapsed())
        self.logger.addHandler(self.handler)
        self.logger.setLevel(logging.INFO)
        return self

    def __exit__(self, *exc):
        self.logger.removeHandler(self.handler)
        self.logger.setLevel(self.level)
        return False
