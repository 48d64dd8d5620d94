"""Every process that runs episodes for training or evaluation runs one thread per library
(torch, numba, BLAS/OpenMP), so that N workers on N cores do not oversubscribe them."""

import subprocess
import sys

from mjexplore.envs import EnvConfig
from mjexplore.learning.train_config import TrainConfig
from mjexplore.learning.vec_envs import make_vec_env


def test_training_workers_run_one_thread_per_library():
    import os

    from mjexplore.episode.workers import THREAD_VARIABLES

    before = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    config = TrainConfig(n_envs=2, env=EnvConfig(scenes=("train_loop",)))
    venv = make_vec_env(config, seed=0)
    try:
        counts = venv.get_attr("worker_threads")
    finally:
        venv.close()
    assert counts == [{"blas_openmp": 1, "torch": 1, "numba": 1}] * 2
    # The learner keeps its own settings (numba refuses a thread count changed under it).
    assert {name: os.environ.get(name) for name in THREAD_VARIABLES} == before


def test_a_limited_process_caps_pools_that_were_loaded_before():
    # numpy's BLAS and torch load with a pool per core; limit_threads caps them at run time.
    code = ("import os; os.environ.pop('OMP_NUM_THREADS', None)\n"
            "import numpy, torch, numba\n"
            "from mjexplore.episode.workers import limit_threads, thread_counts\n"
            "torch.set_num_threads(2)\n"
            "numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))\n"
            "limit_threads(); print(sorted(thread_counts().items()))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[('blas_openmp', 1), ('numba', 1), ('torch', 1)]"


def _compile_fresh_function() -> int:
    import numba

    @numba.njit  # Defined here: never in numba's cache, so it compiles in the worker.
    def increment(x):
        return x + 1

    return increment(1) + numba.get_num_threads()


def test_an_episode_worker_still_compiles_after_its_threads_are_limited():
    # numba loads (with its default pool size) before the worker's initializer caps it: a
    # compilation after that once raised "Cannot set NUMBA_NUM_THREADS ..." in every bench
    # worker that met an explorer not yet in numba's cache.
    import multiprocessing

    from mjexplore.episode.workers import init_episode_worker

    with multiprocessing.get_context("spawn").Pool(1, initializer=init_episode_worker) as pool:
        assert pool.apply(_compile_fresh_function) == 2 + 1
