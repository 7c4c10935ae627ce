"""Progress of the long runs (validation, diagnosis, the improve loop, identification with
structure selection): one line per stage, through the ``lpvpc.progress`` logger at INFO.

The library never prints: the command line shows these lines on stderr unless ``-q``;
in Python, show them with :mod:`logging` (see :func:`report`).
"""

import logging

logger = logging.getLogger(__name__)
logger.propagate = False  # not one of the library's notes (-v): shown on its own, unless -q


def report(message: str) -> None:
    """One progress line (what is about to run, or what just finished).

    >>> import logging, sys
    >>> handler = logging.StreamHandler(sys.stdout)
    >>> logging.getLogger("lpvpc.progress").addHandler(handler)
    >>> logging.getLogger("lpvpc.progress").setLevel(logging.INFO)
    >>> report("validate: co-simulation")
    validate: co-simulation
    >>> logging.getLogger("lpvpc.progress").removeHandler(handler)
    """
    logger.info(message)
