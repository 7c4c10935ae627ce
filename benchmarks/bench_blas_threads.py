"""The diagnosis in a Python session: BLAS's default threads against one.

A notebook imports lpvpc after BLAS has started its threads (2 on this machine), so the
command line's ``OPENBLAS_NUM_THREADS=1`` does not reach it; ``identify``, ``diagnose`` and
``improve`` run inside ``lpvpc.linalg.one_blas_thread`` instead. This times the diagnosis
both ways in one run (the function as decorated, and its undecorated body under BLAS's 2
threads) on population draw 10106 (drifting activation: its between-record candidates run
too). Run with no thread variable set::

    env -u OPENBLAS_NUM_THREADS python benchmarks/bench_blas_threads.py
"""

import inspect
import os
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import lpvpc  # noqa: E402
from lpvpc.diagnosis.diagnose import diagnose  # noqa: E402
from lpvpc.linalg import BLAS_THREAD_VARIABLES  # noqa: E402
from lpvpc.simulation.population import draw_subject, simulate_subject  # noqa: E402
from _results import write_results  # noqa: E402

REPEATS = 3


def best_of(call):
    """Shortest of REPEATS wall-clock times (s) of ``call()``."""
    times = []
    for _ in range(REPEATS):
        t = time.perf_counter()
        call()
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    set_vars = [v for v in BLAS_THREAD_VARIABLES if v in os.environ]
    if set_vars:
        print(f"skipped: {', '.join(set_vars)} set; this benchmark compares BLAS's default threads with one "
              f"(run it with them unset: env -u {set_vars[0]} python benchmarks/bench_blas_threads.py)")
        return
    from threadpoolctl import threadpool_info, threadpool_limits

    default = max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
    s = draw_subject(10106)
    ident, novel = simulate_subject(s), simulate_subject(s, "novel")
    a, b = lpvpc.pair_trials(ident.pt, ident.ut), lpvpc.pair_trials(novel.pt, novel.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = lpvpc.identify(a)
        body = inspect.unwrap(diagnose)
        with threadpool_limits(limits=default, user_api="blas"):  # a session's BLAS, threads started
            t_many = best_of(lambda: body(model, b, reference=a))  # the body without its one-thread context
            t_one = best_of(lambda: diagnose(model, b, reference=a))  # as decorated
    lines = ["# BLAS threads in a Python session (env -u OPENBLAS_NUM_THREADS python benchmarks/bench_blas_threads.py)",
             "", f"Population draw 10106, 2-minute 1 kHz records paired at 100 Hz; best of {REPEATS}; BLAS's default "
             f"{default} threads on {os.cpu_count()} cores.", "",
             "| step | default threads s | one thread s | ratio |", "|---|---|---|---|",
             f"| diagnose(model, novel, reference=ident) | {t_many:.2f} | {t_one:.2f} | {t_many / t_one:.1f} |", "",
             "Identification's own ratio: identify_floor.txt."]
    write_results("blas_threads.txt", lines, echo=True)


if __name__ == "__main__":
    main()
