"""The golden master of single-robot results: hashes that stay bit-identical through the
"one engine" refactor (issue 50), so that every step of it can show it changed nothing.

Cases (56):

* ``episode/WORLD/LOCALIZATION/EXPLORER/seedS``: one ``explore`` run folder each, over
  worlds {physics, kinematic, grid} x localizations {ground_truth, odometry, scan_matching}
  x explorers {nearest, gvn (its shipped default model), oracle} x seeds {0, 1}, on the
  canonical ``train_loop`` scene (16 x 16 m) with a 30 s cap of simulated time; the
  settings are those ``mjexplore explore`` builds (ideal lidar, 0.01 m noise), with the
  typical wheel odometry errors for the odometry and scan-matching localizers. The run
  folder is written by :func:`mjexplore.eval.run.write_run`; the sha256 of
  ``metrics.json``, ``ratio.csv`` and ``kinematics.csv`` are kept.
* ``env/gymnasium``: 50 steps of the GVN training env (``training/gvn_v3.yaml``'s
  ``ExplorationEnv``, reset with seed 0), taking the first valid action of the mask; one
  sha256 per step over the observation, reward, terminated and truncated (and the
  observation of a reset when an episode ended).
* ``env/pettingzoo``: the same for 50 steps of the team env
  (:class:`~mjexplore.envs.team.TeamExplorationEnv`, its defaults, seed 0).

Every case runs with one thread each of torch, numba and BLAS (as the episode workers do),
so the hashes do not depend on the cores. Floating-point results may still differ on another
CPU or library build: the stored file names the platform it was written on, and a check
on another platform compares nothing (``tests/test_golden_master.py`` skips).

Usage:
    python tools/golden_master.py                 # --check: compare with the stored hashes
    python tools/golden_master.py --only physics  # check the cases whose name holds 'physics'
    python tools/golden_master.py --write         # rewrite tests/data/golden_master.json

``--check`` prints one JSON line, ``{"cases": N, "mismatches": [...], ...}``, and exits 1 on
a mismatch. Rewrite only for an intended change of results, never to make a refactor pass.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
GOLDEN_PATH = REPO / "tests" / "data" / "golden_master.json"

SCENE = "train_loop"
WORLDS = ("physics", "kinematic", "grid")
LOCALIZATIONS = ("ground_truth", "odometry", "scan_matching")
EXPLORERS = ("nearest", "gvn", "oracle")
SEEDS = (0, 1)
# Simulated seconds per episode: 7-15 decisions of nearest and gvn, 2 of the oracle (its
# first plan covers the scene), every episode ends at the cap; about 1 s of CPU each
# (scan matching about 1.8 s).
MAX_TIME_S = 30.0
LIDAR_NOISE_M = 0.01  # ``mjexplore explore``'s ideal lidar noise.
ENV_STEPS = 50
ENV_SEED = 0
GYM_RECIPE = REPO / "training" / "gvn_v3.yaml"

RUN_FILES = ("metrics.json", "ratio.csv", "kinematics.csv")
# Keys of metrics.json that legitimately vary between two runs of the same case (wall-clock
# times, git revision, dates, host), dropped before hashing. Measured by running every case
# twice and comparing the files byte for byte: there are none. The run's git revision and
# absolute scene path are in config.json, which is not hashed; metrics.json, ratio.csv and
# kinematics.csv hold simulated quantities only. List a key here if one ever appears.
VOLATILE_METRICS: tuple[str, ...] = ()
# The platform that the stored hashes are meaningful on.
FINGERPRINT_MODULES = ("numpy", "mujoco", "numba", "torch")

Parts = dict[str, str]  # Part of a case (a file, a step) -> sha256 hex digest.


# ---------------------------------------------------------------------- platform


def cpuinfo_field(*keys: str) -> str | None:
    """The value of the first line of /proc/cpuinfo whose key is one of ``keys`` (None where
    there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in keys:
            return value.strip()
    return None


def platform_fingerprint() -> dict[str, str | None]:
    """The library versions, machine and CPU model that floating-point results depend on."""
    import importlib

    found: dict[str, str | None] = {
        name: importlib.import_module(name).__version__ for name in FINGERPRINT_MODULES}
    found["machine"] = platform.machine()
    found["cpu"] = cpuinfo_field("model name", "Model", "cpu model")
    # A virtual machine's model name can be generic; the instruction sets (numpy's dispatch)
    # and the CPU numba compiles for decide the last bits of a result too.
    flags = cpuinfo_field("flags", "Features")
    found["cpu_flags_sha256"] = (None if flags is None else hashlib.sha256(
        " ".join(sorted(flags.split())).encode()).hexdigest()[:16])
    found["numba_cpu"] = _numba_cpu()
    return found


def _numba_cpu() -> str | None:
    """The CPU name numba's compiler targets on this machine (its setting NUMBA_CPU_NAME
    included); None where this numba does not say."""
    from numba.core.codegen import JITCPUCodegen

    try:
        return JITCPUCodegen("golden_master")._get_host_cpu_name()
    except AttributeError:
        return None


def platform_differences(stored: dict[str, Any]) -> list[str]:
    """``name: stored -> here`` for each entry of the fingerprint that differs here."""
    here = platform_fingerprint()
    return [f"{k}: {stored.get(k)!r} -> {here.get(k)!r}"
            for k in sorted(set(here) | set(stored)) if stored.get(k) != here.get(k)]


@contextlib.contextmanager
def one_thread_each() -> Iterator[None]:
    """Within the block, one thread for torch, numba and BLAS/OpenMP
    (:func:`~mjexplore.episode.workers.limit_threads`, as in every episode worker); torch's
    and BLAS's thread counts and the thread variables are restored after it, numba's
    where numba allows (a pool that had not started keeps one thread)."""
    import numba
    import torch
    from threadpoolctl import threadpool_limits

    from mjexplore.episode.workers import THREAD_VARIABLES, limit_threads

    saved_env = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    torch_threads, numba_threads = torch.get_num_threads(), numba.get_num_threads()
    with threadpool_limits(limits=None):  # Restores the BLAS pools on exit.
        limit_threads()
        try:
            yield
        finally:
            torch.set_num_threads(torch_threads)
            if numba_threads <= numba.config.NUMBA_NUM_THREADS:
                numba.set_num_threads(numba_threads)
            for name, value in saved_env.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value


# ---------------------------------------------------------------------- episodes


@dataclasses.dataclass(frozen=True)
class EpisodeCase:
    """One single-robot episode of the golden master.

    Attributes:
        world: ``SimConfig.dynamics``: 'physics', 'kinematic' or 'grid'.
        localization: ``EpisodeConfig.localization``.
        explorer: A method name of :mod:`mjexplore.eval.methods`.
        seed: Episode seed (start jitter, noise, odometry errors).
    """

    world: str
    localization: str
    explorer: str
    seed: int

    @property
    def name(self) -> str:
        return f"episode/{self.world}/{self.localization}/{self.explorer}/seed{self.seed}"


def episode_cases() -> list[EpisodeCase]:
    """Every episode case, in a fixed order."""
    return [EpisodeCase(w, loc, e, s) for w in WORLDS for loc in LOCALIZATIONS
            for e in EXPLORERS for s in SEEDS]


def episode_config(case: EpisodeCase):
    """The case's settings: ``mjexplore explore``'s (ideal lidar with 0.01 m noise at the
    profile's range), the case's world and localizer, typical odometry errors unless the
    robot localizes on the ground truth, and the :data:`MAX_TIME_S` cap."""
    from mjexplore.episode import EpisodeConfig
    from mjexplore.robot import motion_profile
    from mjexplore.sim.lidar import lidar_model
    from mjexplore.sim.simulator import SimConfig

    profile = "sim"
    lidar = lidar_model("ideal", noise_std=LIDAR_NOISE_M,
                        range_max=motion_profile(profile).lidar_range)
    odometry_error = "none" if case.localization == "ground_truth" else "typical"
    return EpisodeConfig(max_time=MAX_TIME_S, localization=case.localization,
                         sim=SimConfig(profile=profile, lidar=lidar, dynamics=case.world,
                                       odometry_error=odometry_error))


@contextlib.contextmanager
def _no_figure_rendering() -> Iterator[None]:
    """Within the block matplotlib figures are built but not rendered (``savefig`` writes
    nothing): the run folder's PNGs are not hashed and rendering them costs about 0.8 s
    per episode, as much as the episode."""
    from matplotlib.figure import Figure

    original = Figure.savefig
    Figure.savefig = lambda self, *args, **kwargs: None
    try:
        yield
    finally:
        Figure.savefig = original


def file_digest(path: Path) -> str:
    """sha256 of a run file's bytes (``metrics.json`` without :data:`VOLATILE_METRICS`)."""
    data = path.read_bytes()
    if path.name == "metrics.json" and VOLATILE_METRICS:
        metrics = json.loads(data)
        for key in VOLATILE_METRICS:
            metrics.pop(key, None)
        data = (json.dumps(metrics, indent=2) + "\n").encode("utf-8")
    return hashlib.sha256(data).hexdigest()


def episode_parts(case: EpisodeCase) -> Parts:
    """Runs the case into a temporary run folder and hashes its :data:`RUN_FILES`."""
    from mjexplore.eval.methods import parse_method
    from mjexplore.eval.run import write_run
    from mjexplore.scenes.canonical import resolve_scene

    spec = parse_method(case.explorer)
    with tempfile.TemporaryDirectory(prefix="golden-master-") as tmp, _no_figure_rendering():
        out = Path(tmp) / "run"
        # As `mjexplore explore` calls it: filed under the label, built from the spec.
        write_run(out, resolve_scene(SCENE), spec.label, case.seed, episode_config(case),
                  mcap=False, spec=spec.text)
        return {name: file_digest(out / name) for name in RUN_FILES}


# ---------------------------------------------------------------------- envs


def _hash_array(h: Any, value: Any) -> None:
    """Feeds an array's dtype, shape and bytes (C order) to the hash ``h``."""
    a = np.ascontiguousarray(value)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())


def _hash_observation(h: Any, obs: dict[str, Any]) -> None:
    """Feeds a Dict observation to ``h``, its entries in key order (nested dicts too)."""
    for key in sorted(obs):
        h.update(key.encode())
        if isinstance(obs[key], dict):
            _hash_observation(h, obs[key])
        else:
            _hash_array(h, obs[key])


def _first_valid(mask: np.ndarray) -> int:
    """The fixed action rule: the first valid action of a mask (0 when none is)."""
    valid = np.flatnonzero(mask)
    return int(valid[0]) if len(valid) else 0


def gymnasium_parts(steps: int = ENV_STEPS) -> Parts:
    """``steps`` steps of the GVN training env (reset with :data:`ENV_SEED`, again without
    a seed when an episode ends), one sha256 per step, ``reset`` the first."""
    from mjexplore.envs.exploration import ExplorationEnv
    from mjexplore.learning.train_config import load_train_config

    config = load_train_config(GYM_RECIPE).env
    with tempfile.TemporaryDirectory(prefix="golden-master-") as tmp:
        # Layouts generated afresh here, not read from a cache an older generator filled.
        config = dataclasses.replace(config, procedural=dataclasses.replace(
            config.procedural, cache_dir=tmp))
        env = ExplorationEnv(config)
        obs, _ = env.reset(seed=ENV_SEED)
        h = hashlib.sha256()
        _hash_observation(h, obs)
        parts = {"reset": h.hexdigest()}
        for k in range(1, steps + 1):
            h = hashlib.sha256()
            action = _first_valid(env.action_masks())
            obs, reward, terminated, truncated, _ = env.step(action)
            _hash_observation(h, obs)
            _hash_array(h, np.array([action], np.int64))
            _hash_array(h, np.array([reward], np.float64))
            _hash_array(h, np.array([terminated, truncated], np.bool_))
            if terminated or truncated:
                obs, _ = env.reset()
                _hash_observation(h, obs)
            parts[f"step_{k:02d}"] = h.hexdigest()
        env.close()
    return parts


def pettingzoo_parts(steps: int = ENV_STEPS) -> Parts:
    """``steps`` steps of the team env (its defaults; reset with :data:`ENV_SEED`, again
    when every agent is done), one sha256 per step, ``reset`` the first; agents in name
    order."""
    from mjexplore.envs.team import TeamExplorationEnv

    env = TeamExplorationEnv()
    obs, _ = env.reset(seed=ENV_SEED)
    h = hashlib.sha256()
    _hash_observation(h, obs)
    parts = {"reset": h.hexdigest()}
    for k in range(1, steps + 1):
        h = hashlib.sha256()
        actions = {a: _first_valid(obs[a]["action_mask"]) for a in sorted(obs)}
        obs, rewards, terminations, truncations, _ = env.step(actions)
        _hash_observation(h, obs)
        for agent in sorted(set(rewards) | set(actions)):
            h.update(agent.encode())
            _hash_array(h, np.array([actions.get(agent, -1)], np.int64))
            _hash_array(h, np.array([rewards.get(agent, np.nan)], np.float64))
            _hash_array(h, np.array([terminations.get(agent, False),
                                     truncations.get(agent, False)], np.bool_))
        if not env.agents:
            obs, _ = env.reset()
            _hash_observation(h, obs)
        parts[f"step_{k:02d}"] = h.hexdigest()
    env.close()
    return parts


# ---------------------------------------------------------------------- cases


def cases() -> dict[str, Callable[[], Parts]]:
    """Every case by name, in a fixed order: the function that computes its hashes."""
    out: dict[str, Callable[[], Parts]] = {
        c.name: (lambda c=c: episode_parts(c)) for c in episode_cases()}
    out["env/gymnasium"] = gymnasium_parts
    out["env/pettingzoo"] = pettingzoo_parts
    return out


def compute_case(name: str) -> Parts:
    """The hashes of one case, computed with one thread per library."""
    with one_thread_each():
        return cases()[name]()


def settings() -> dict[str, Any]:
    """The case settings, stored beside the hashes for the reader."""
    return {"scene": SCENE, "max_time_s": MAX_TIME_S, "lidar_noise_m": LIDAR_NOISE_M,
            "seeds": list(SEEDS), "env_steps": ENV_STEPS, "env_seed": ENV_SEED,
            "gym_recipe": str(GYM_RECIPE.relative_to(REPO)),
            "volatile_metrics_dropped": list(VOLATILE_METRICS)}


def compare(name: str, expected: Parts | None, actual: Parts) -> dict[str, Any] | None:
    """A mismatch record of one case (None when it matches): the parts that differ."""
    if expected is None:
        return {"case": name, "parts": ["(not in the golden master)"]}
    differ = [p for p in sorted(set(expected) | set(actual))
              if expected.get(p) != actual.get(p)]
    return {"case": name, "parts": differ} if differ else None


def load_golden(path: Path = GOLDEN_PATH) -> dict[str, Any]:
    """The stored golden master: ``platform``, ``settings`` and ``cases``."""
    return json.loads(path.read_text(encoding="utf-8"))


def write_golden(computed: dict[str, Parts], path: Path = GOLDEN_PATH) -> None:
    """Writes the golden master atomically (a temporary file, then a rename)."""
    from mjexplore.io.atomic import write_text_atomic

    path.parent.mkdir(parents=True, exist_ok=True)
    data = {"platform": platform_fingerprint(), "settings": settings(), "cases": computed}
    write_text_atomic(path, json.dumps(data, indent=1) + "\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true",
                      help="compare with the stored golden master (the default)")
    mode.add_argument("--write", action="store_true",
                      help="rewrite it: only for an intended change of results")
    parser.add_argument("--only", default=None,
                        help="check only the cases whose name contains this text")
    parser.add_argument("--golden", type=Path, default=GOLDEN_PATH,
                        help="the golden master file (default: %(default)s)")
    args = parser.parse_args()
    if args.write and args.only:
        parser.error("--write rewrites every case: drop --only")
    names = [n for n in cases() if args.only is None or args.only in n]
    if not names:
        parser.error(f"no case name contains {args.only!r}")
    if not args.write and not args.golden.is_file():
        parser.error(f"no golden master at {args.golden}: write it with --write")
    start = time.perf_counter()
    computed = {name: compute_case(name) for name in names}
    seconds = round(time.perf_counter() - start, 1)
    if args.write:
        write_golden(computed, args.golden)
        print(json.dumps({"cases": len(computed), "written": str(args.golden),
                          "seconds": seconds}))
        return 0
    golden = load_golden(args.golden)
    mismatches = [m for n in names
                  if (m := compare(n, golden["cases"].get(n), computed[n])) is not None]
    if args.only is None:  # Cases stored but no longer computed.
        mismatches += [{"case": n, "parts": ["(no longer a case)"]}
                       for n in golden["cases"] if n not in computed]
    report: dict[str, Any] = {"cases": len(computed), "mismatches": mismatches,
                              "seconds": seconds}
    if differs := platform_differences(golden["platform"]):
        report["platform_differs"] = differs  # Mismatches may be the platform's.
    print(json.dumps(report))
    return 1 if mismatches else 0


if __name__ == "__main__":
    sys.exit(main())
