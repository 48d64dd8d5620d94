"""Worker processes that run episodes: one thread per library each, and bounded memory.

Threads: torch, numba and the BLAS under numpy each start a thread pool sized to every
core in every process. Fifteen env workers on a 16-core machine then ran ~200 threads and
collected 5.5 decisions/s where one thread each gave 78. So every worker runs one thread
of each (:func:`limit_threads`), and a process about to start workers first sets the
thread variables its children inherit before their libraries load
(:func:`single_thread_children`); the learner keeps the cores that are left.

Memory:

Maps of millions of cells make every decision allocate and free multi-megabyte temporaries
(masks, distance fields). glibc's malloc raises its mmap threshold after each large free
(up to 32 MB), after which such blocks come from the heap, where fragmentation keeps them:
a 100 x 100 m office episode grew from 1.7 to 2.9 GB resident by its end
(tools/bench_long_episode.py). Fixing the threshold at 128 KiB (which also turns off the
dynamic adjustment) returns every large block to the system when freed: the same episode
peaked at 1.0 GB. No-op where the C library is not glibc.

A training learner is the opposite case: each PPO minibatch allocates and frees the same
tensors of up to tens of megabytes, and with that threshold every one is mapped afresh and
faulted in page by page (5.6 million page faults, 41 % of the time in the kernel, on a
benchmark of 12 minibatches that takes 9.6 s instead of 16.3 s with the heap reused).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import sys
from collections.abc import Iterator

log = logging.getLogger(__name__)

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
M_MMAP_MAX = -4
THRESHOLD_BYTES = 128 * 1024
LEARNER_TRIM_BYTES = 1 << 30


def _mallopt(settings: tuple[tuple[int, int], ...]) -> bool:
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        ok = all([bool(libc.mallopt(option, value)) for option, value in settings])
    except (OSError, AttributeError):
        return False
    log.debug("mallopt %s: %s", settings, ok)
    return ok


def bound_heap_growth() -> bool:
    """Sets glibc's mmap and trim thresholds for long episodes on large maps (see the
    module docstring); True if set."""
    return _mallopt(((M_MMAP_THRESHOLD, THRESHOLD_BYTES), (M_TRIM_THRESHOLD, THRESHOLD_BYTES)))


def reuse_freed_memory() -> bool:
    """Makes glibc serve every block from the heap and keep up to 1 GiB of freed memory
    there, for a training learner (see the module docstring); True if set."""
    return _mallopt(((M_MMAP_MAX, 0), (M_TRIM_THRESHOLD, LEARNER_TRIM_BYTES)))


# The variables torch (OpenMP, MKL), numba and the BLAS libraries read when they load.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                    "NUMBA_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


@contextlib.contextmanager
def thread_environment(value: str | None) -> Iterator[None]:
    """Within the block every variable of :data:`THREAD_VARIABLES` is ``value`` (None:
    unset, the libraries' defaults); this process's environment is restored after it."""
    saved = {name: os.environ.pop(name, None) for name in THREAD_VARIABLES}
    if value is not None:
        os.environ.update(dict.fromkeys(THREAD_VARIABLES, value))
    try:
        yield
    finally:
        for name, old in saved.items():
            if old is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = old


def single_thread_children() -> contextlib.AbstractContextManager[None]:
    """Within the block, the processes this one starts (and a forkserver it starts) load
    their libraries with one thread each; this process's environment is restored after
    it (numba refuses a thread count that changes once its threads run)."""
    return thread_environment("1")


def _numba_threads_running() -> bool:
    """Whether numba's thread pool has started in this process (its size is fixed then)."""
    if "numba" not in sys.modules:
        return False
    from numba.np.ufunc import parallel

    return bool(getattr(parallel, "_is_initialized", False))


def limit_threads() -> None:
    """One thread for torch, numba and BLAS/OpenMP in this process, for the libraries
    loaded already (their pools are capped at run time) and those loaded later."""
    running = _numba_threads_running()
    os.environ.update({name: "1" for name in THREAD_VARIABLES
                       if not (running and name == "NUMBA_NUM_THREADS")})
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    if "numba" in sys.modules:
        if not running:
            # numba read its pool size when it loaded; read it again before the pool starts,
            # or its next compilation finds the variable changed under a running pool and
            # raises (a worker's first JIT compile of an explorer not yet in the cache).
            from numba.core.config import reload_config

            reload_config()
        sys.modules["numba"].set_num_threads(1)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def thread_counts() -> dict[str, int]:
    """The threads each library of this process would use now: torch's intra-op threads,
    numba's, and the most of any BLAS or OpenMP pool loaded (threadpoolctl)."""
    from threadpoolctl import threadpool_info

    counts = {"blas_openmp": max((p["num_threads"] for p in threadpool_info()), default=1)}
    if "torch" in sys.modules:
        counts["torch"] = sys.modules["torch"].get_num_threads()
    if "numba" in sys.modules:
        counts["numba"] = sys.modules["numba"].get_num_threads()
    return counts


def init_episode_worker() -> None:
    """Sets up a worker process that runs episodes, one per core: one thread per library
    (:func:`limit_threads`) and a bounded heap (:func:`bound_heap_growth`)."""
    limit_threads()
    bound_heap_growth()
