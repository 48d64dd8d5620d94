"""A sweep's episodes as Ray tasks, on this machine or on a cluster that shares no files.

Each task gets its job and the episode settings, and as data the scene's files and, for a
learned explorer given by path, its weights (each put once in Ray's object store and
unpacked once per machine: :mod:`mjexplore.io.bundle`). It runs the episode with the code
the process pool runs (:func:`mjexplore.eval.sweep.run_job`) into a run
folder in its own temporary directory and returns that folder's files, which the sweep
writes as the run folder (:func:`mjexplore.eval.sweep.file_results`). An
episode depends on its scene, method, seed and settings alone, so the run folders are those
``--workers`` makes, bit for bit (``config.json`` names the scene as it was given here).
"""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

import ray

from mjexplore.episode.workers import init_episode_worker
from mjexplore.eval.methods import LEARNED, parse_method
from mjexplore.explorers.team import TEAM_METHODS
from mjexplore.io.bundle import Bundle, pack_folder, unpack
from mjexplore.io.ray_cluster import connect, map_unordered
from mjexplore.policies.models import (
    WEIGHTS_NAME,
    register_copy,
    resolve_policy,
    shipped_models,
)
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.scene import load_scene_files


@dataclasses.dataclass(frozen=True)
class _Scene:
    """A scene as it travels (its files go beside it): its folder's and its MJCF's names,
    and where it was given."""

    folder: str
    xml: str
    origin: str


@dataclasses.dataclass(frozen=True)
class _Policy:
    """Weights given by path, as they travel (the file goes beside): the spec's policy as
    given and the name this machine resolves it to."""

    policy: str
    name: str


def _policy_files(spec_text: str) -> tuple[_Policy, Bundle] | None:
    """The weights a spec names by path (None: a classic or team method, or a shipped
    model, which every machine's checkout holds)."""
    if spec_text in TEAM_METHODS:
        return None
    spec = parse_method(spec_text)
    if spec.method not in LEARNED or spec.policy is None or spec.policy in shipped_models():
        return None
    name, path = resolve_policy(spec.policy, spec.method)
    return _Policy(spec.policy, name), {WEIGHTS_NAME: path.read_bytes()}


class SweepJob(Protocol):
    """What :func:`run_remote` needs of a job: its scene as given (and, if it has one, its
    ``spec``: the method spec that builds its explorers)."""

    scene: str


Runner = Callable[..., dict[str, Any]]
"""``runner(job, folder, scene=SceneFiles, spec=str | None)``: runs the job's episode into
the run folder ``folder``; its metrics, or a failure record (``end_reason`` 'error')."""


def _episode_task(run: Runner, job: SweepJob, scene: _Scene, scene_files: Bundle,
                  policy: _Policy | None, policy_files: Bundle | None
                  ) -> tuple[dict[str, Any], Bundle]:
    """A Ray task: the episode's metrics (or failure record) and its run folder's files."""
    local = load_scene_files(unpack(scene_files, scene.folder) / scene.xml)
    if policy is not None:
        assert policy_files is not None  # They travel together (run_remote).
        register_copy(policy.policy, policy.name,
                      unpack(policy_files, "policy") / WEIGHTS_NAME)
    with tempfile.TemporaryDirectory(prefix="mjexplore-run-") as tmp:
        folder = Path(tmp) / "run"
        metrics = run(job, folder, scene=dataclasses.replace(local, origin=scene.origin),
                      spec=getattr(job, "spec", None))
        files = pack_folder(folder, max_bytes=None) if folder.is_dir() else {}
    return metrics, files


def run_remote(jobs: Sequence[SweepJob], run: Runner,
               failure: Callable[[Any, BaseException], dict[str, Any]], address: str,
               local_cpus: int | None = None
               ) -> Iterator[tuple[Any, dict[str, Any], Bundle]]:
    """Runs ``jobs`` as Ray tasks on the cluster at ``address`` (``local_cpus``: a local
    instance's CPUs); yields ``(job, metrics or failure record, run folder's files)`` as
    each finishes (no files for a failure).

    ``run`` runs one job (:data:`Runner`; a module-level function or a
    ``functools.partial`` of one, which every machine imports); ``failure(job, error)``
    makes the record of a task that did not return (a lost worker).

    Raises:
        UserInputError: no cluster at ``address``; a scene too large to send.
    """
    if not jobs:
        return
    joined = connect(address, local_cpus=local_cpus)
    try:
        scenes, scene_files = {}, {}
        for name in dict.fromkeys(job.scene for job in jobs):
            files = resolve_scene(name)
            scenes[name] = _Scene(files.xml.parent.name, files.xml.name, files.source)
            scene_files[name] = ray.put(pack_folder(files.xml.parent))
        policies: dict[str | None, tuple[_Policy | None, Any]] = {}
        for spec in dict.fromkeys(getattr(job, "spec", None) for job in jobs):
            weights = None if spec is None else _policy_files(spec)
            policies[spec] = (None, None) if weights is None else (weights[0],
                                                                   ray.put(weights[1]))
        calls = [(run, job, scenes[job.scene], scene_files[job.scene],
                  *policies[getattr(job, "spec", None)]) for job in jobs]
        for index, result, error in map_unordered(_episode_task, calls,
                                                  initializer=init_episode_worker):
            if error is not None:
                yield jobs[index], failure(jobs[index], error), {}
            else:
                yield jobs[index], *result
    finally:
        if joined:
            ray.shutdown()
