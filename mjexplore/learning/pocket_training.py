"""Training the frontier-pocket predictor (:mod:`mjexplore.topology.pockets`) by supervision.

Episodes on generated layouts (the training env's families, sizes and episode settings;
the grid world by default) are driven by nearest-frontier, or, in a share of them, by
nearest-frontier that passes over frontiers whose true pocket is small (so the data also
hold the states that the predictor's users reach). At every decision a share of the
reachable frontiers is kept: its map patch, its length and its true pocket area from the
ground truth. :class:`~mjexplore.topology.pockets.PocketNet` is then fitted to "the pocket
is below ``small_area_m2``" by binary cross-entropy, each patch turned and mirrored at
random (the eight symmetries of the square: a map has no preferred axis). Every tenth
episode is held out for validation; the fit's figures are written beside the weights.

``mjexplore train-pockets --config training/pockets.yaml --out runs/train/pockets``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import multiprocessing as mp
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.config import load_yaml_config, to_dict
from mjexplore.envs.exploration import EnvConfig
from mjexplore.episode.explorer import ExplorationState
from mjexplore.errors import UserInputError
from mjexplore.io.atomic import refuse_foreign_files, write_text_atomic
from mjexplore.io.progress import Progress
from mjexplore.io.provenance import git_revision

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PocketTrainingConfig:
    """Data collection and fit of the pocket predictor.

    Attributes:
        env: Layouts (``procedural``) and episode settings of the collection episodes, as in
            a training config.
        episodes: Collection episodes; episode ``i`` resets the env with seed ``seed + i``.
        seed: First episode seed, and the seed of the frontier sampling and of the fit.
        small_area_m2: A pocket below this area is "small" (what the network predicts), m^2.
        frontier_share: Share of the reachable frontiers kept at each decision.
        skip_share: Share of the episodes driven by nearest-frontier passing over frontiers
            whose true pocket is small (the others by nearest-frontier).
        validation_every: Every this many episodes one is held out for validation.
        epochs: Passes over the training patches.
        batch_size: Patches per gradient step.
        learning_rate: Adam's step size.
        threads: Torch threads of the fit.
    """

    env: EnvConfig
    episodes: int = 500
    seed: int = 0
    small_area_m2: float = 0.5
    frontier_share: float = 0.5
    skip_share: float = 0.5
    validation_every: int = 10
    epochs: int = 4
    batch_size: int = 256
    learning_rate: float = 1e-3
    threads: int = 2

    def __post_init__(self) -> None:
        if self.env.procedural is None:
            raise ValueError("env.procedural must name the generated layouts to learn from")
        if self.episodes < 2 or self.validation_every < 2:
            raise ValueError("episodes and validation_every must be >= 2")
        if not 0 < self.frontier_share <= 1 or not 0 <= self.skip_share <= 1:
            raise ValueError("frontier_share must be in (0, 1], skip_share in [0, 1]")
        if self.small_area_m2 <= 0 or self.epochs < 1 or self.batch_size < 1:
            raise ValueError("small_area_m2 must be > 0, epochs and batch_size >= 1")


def load_pocket_config(path: str | Path) -> PocketTrainingConfig:
    """Reads a pocket-training YAML (see training/pockets.yaml)."""
    return load_yaml_config(PocketTrainingConfig, path)


class _Recorder:
    """Nearest-frontier (optionally passing over small true pockets) that keeps a sample
    of the frontiers it sees at each decision."""

    name = "pocket_recorder"

    def __init__(self, rng: np.random.Generator, share: float, small_area_m2: float,
                 skip_small: bool) -> None:
        self.rng, self.share = rng, share
        self.small_area_m2, self.skip_small = small_area_m2, skip_small
        self.patches: list[np.ndarray] = []
        self.lengths: list[np.ndarray] = []
        self.areas: list[np.ndarray] = []

    def reset(self, rng: np.random.Generator) -> None:
        del rng

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        from mjexplore.topology.pockets import frontier_lengths, frontier_patches, pocket_areas

        if not state.frontiers:
            return None
        distance = state.frontier_distances()
        assert state.ground_truth is not None  # An Episode's scene has one.
        area = pocket_areas(state.grid, state.ground_truth, state.frontiers)
        keep = np.flatnonzero(np.isfinite(distance)
                              & (self.rng.random(len(distance)) < self.share))
        if len(keep):
            kept = [state.frontiers[i] for i in keep]
            self.patches.append(frontier_patches(state.grid, kept))
            self.lengths.append(frontier_lengths(state.grid, kept))
            self.areas.append(area[keep].astype(np.float32))
        return nearest_goal(state, distance, area if self.skip_small else None,
                            self.small_area_m2)


def nearest_goal(state: ExplorationState, distance: np.ndarray, area: np.ndarray | None = None,
                 small_area_m2: float = 0.5) -> np.ndarray | None:
    """Nearest-frontier's goal from the frontiers' path ``distance`` (m); with their true
    pocket ``area`` (m^2) it passes over those below ``small_area_m2`` unless no other is
    reachable. None when none is reachable."""
    if area is not None:
        large = np.where(area >= small_area_m2, distance, np.inf)
        if np.isfinite(large).any():
            distance = large
    if not np.isfinite(distance).any():
        return None
    return state.frontiers[int(np.argmin(distance))].goal


def episode_layout(env: EnvConfig, seed: int):
    """The scene, simulator seed and episode settings of the training env's episode ``seed``
    (its generated layout, start and settings; the env's observation is not built)."""
    from mjexplore.envs import ExplorationEnv

    observation = dataclasses.replace(env.observation, features="v1", pockets=None,
                                      pockets_sha256=None)
    made = ExplorationEnv(dataclasses.replace(env, observation=observation))
    made.reset(seed=seed)
    episode = made.episode
    assert episode is not None  # Set by reset().
    made.close()
    return episode.scene, episode.sim.config.seed, episode.config


def collect_episode(config: PocketTrainingConfig, index: int) -> dict[str, Any]:
    """Patches (uint8 (n, 3, S, S)), lengths (m) and true pocket areas (m^2) of episode
    ``index``, and ``index`` itself."""
    import torch

    from mjexplore.episode import Episode
    from mjexplore.topology.pockets import PATCH_CELLS, PATCH_CHANNELS

    torch.set_num_threads(1)
    scene, sim_seed, episode = episode_layout(config.env, config.seed + index)
    rng = np.random.default_rng([config.seed, index])
    skip = bool(rng.random() < config.skip_share)
    recorder = _Recorder(rng, config.frontier_share, config.small_area_m2, skip)
    Episode(scene, recorder, sim_seed, episode).run()
    empty = np.zeros((0, len(PATCH_CHANNELS), PATCH_CELLS, PATCH_CELLS), np.uint8)
    return {"patches": np.concatenate(recorder.patches) if recorder.patches else empty,
            "lengths": np.concatenate(recorder.lengths) if recorder.lengths else np.zeros(0),
            "areas": np.concatenate(recorder.areas) if recorder.areas else np.zeros(0),
            "index": index}


def _collect_job(args: tuple[PocketTrainingConfig, int]) -> dict[str, Any]:
    return collect_episode(*args)


def collect(config: PocketTrainingConfig, workers: int = 1,
            progress: Progress | None = None) -> dict[str, np.ndarray]:
    """All episodes' samples, with ``validation`` (bool per sample) marking held-out ones;
    ``progress`` counts the episodes collected."""
    jobs = [(config, i) for i in range(config.episodes)]
    parts = []
    done: Iterator[dict[str, Any]]
    with contextlib.ExitStack() as stack:
        if workers > 1:
            pool = stack.enter_context(mp.get_context("spawn").Pool(workers))
            done = pool.imap(_collect_job, jobs, chunksize=1)
        else:
            done = map(_collect_job, jobs)
        for part in done:
            parts.append(part)
            if progress is not None:
                progress.update()
    validation = [np.full(len(p["areas"]), p["index"] % config.validation_every == 0)
                  for p in parts]
    return {"patches": np.concatenate([p["patches"] for p in parts]),
            "lengths": np.concatenate([p["lengths"] for p in parts]).astype(np.float32),
            "areas": np.concatenate([p["areas"] for p in parts]).astype(np.float32),
            "validation": np.concatenate(validation)}


def _symmetry(x, k: int, flip: bool):
    import torch

    x = torch.rot90(x, k, (2, 3))
    return (torch.flip(x, (3,)) if flip else x).contiguous()


def fit(config: PocketTrainingConfig, data: dict[str, np.ndarray],
        progress: Progress | None = None):
    """Fits a fresh :class:`PocketNet`; returns it and its validation figures.
    ``progress`` counts the epochs.

    Raises:
        UserInputError: no samples in the training or the validation episodes.
    """
    import torch

    from mjexplore.topology.pockets import PocketNet

    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    rng = np.random.default_rng(config.seed)
    small = data["areas"] < config.small_area_m2
    train_rows = np.flatnonzero(~data["validation"])
    val_rows = np.flatnonzero(data["validation"])
    if len(train_rows) == 0 or len(val_rows) == 0:
        raise UserInputError("pocket training needs samples in both the training and the "
                             "validation episodes (every validation_every-th episode is "
                             "held out): collect more episodes (--episodes).")
    net = PocketNet()
    optimiser = torch.optim.Adam(net.parameters(), lr=config.learning_rate)
    loss_fn = torch.nn.BCEWithLogitsLoss()

    def tensors(rows):
        return (torch.from_numpy(data["patches"][rows]), torch.from_numpy(data["lengths"][rows]),
                torch.from_numpy(small[rows].astype(np.float32)))

    history = []
    for epoch in range(config.epochs):
        net.train()
        order = rng.permutation(train_rows)
        total, steps = 0.0, 0
        for start in range(0, len(order), config.batch_size):
            patches, lengths, target = tensors(np.sort(order[start:start + config.batch_size]))
            patches = _symmetry(patches, int(rng.integers(4)), bool(rng.integers(2)))
            loss = loss_fn(net(patches, lengths), target)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            total, steps = total + loss.item(), steps + 1
        figures = validate(net, data, val_rows, small)
        figures.update(epoch=epoch, train_loss=round(total / max(steps, 1), 4))
        history.append(figures)
        log.info("pocket fit epoch %d: %s", epoch, figures)
        if progress is not None:
            progress.update(detail=f"validation accuracy {figures['accuracy']:.3f}")
    return net, history


def validate(net, data: dict[str, np.ndarray], rows: np.ndarray, small: np.ndarray
             ) -> dict[str, Any]:
    """Accuracy at probability 0.5 on ``rows``, beside always answering the majority class,
    the share of small pockets called small and of larger ones called small."""
    import torch

    net.eval()
    probs = []
    with torch.no_grad():
        for start in range(0, len(rows), 2048):
            r = rows[start:start + 2048]
            probs.append(torch.sigmoid(net(torch.from_numpy(data["patches"][r]),
                                           torch.from_numpy(data["lengths"][r]))).numpy())
    called = np.concatenate(probs) > 0.5
    truth = small[rows]
    return {"validation_samples": int(len(rows)),
            "accuracy": round(float((called == truth).mean()), 4),
            "majority_accuracy": round(float(max(truth.mean(), 1 - truth.mean())), 4),
            "small_called_small": round(float(called[truth].mean()), 4) if truth.any() else None,
            "large_called_small": round(float(called[~truth].mean()), 4) if (~truth).any()
            else None}


def train_pockets(config: PocketTrainingConfig, out: str | Path, workers: int = 1,
                  progress: bool = False) -> dict[str, Any]:
    """Collects, fits and writes ``out/pockets.safetensors`` and ``out/fit.json`` (``out``
    is made only then: a run that fails leaves nothing). ``progress`` shows the episodes
    collected, then the epochs fitted (:class:`~mjexplore.io.progress.Progress`)."""
    from mjexplore.topology.pockets import save_pocket_net

    out = Path(out)
    refuse_foreign_files(out, ("pockets.safetensors", "fit.json", ".*.tmp"),
                         "a train-pockets run")
    revision = git_revision()  # The code that collects and fits, before any later edit.
    started = time.perf_counter()
    with Progress(config.episodes, "train-pockets", "episodes", enabled=progress,
                  phase="collecting") as shown:
        data = collect(config, workers, shown)
    collected = time.perf_counter()
    with Progress(config.epochs, "train-pockets", "epochs", enabled=progress,
                  phase="fitting") as shown:
        net, history = fit(config, data, shown)
    out.mkdir(parents=True, exist_ok=True)
    summary = {"samples": int(len(data["areas"])),
               "small_share": round(float((data["areas"] < config.small_area_m2).mean()), 4),
               "collect_s": round(collected - started, 1),
               "fit_s": round(time.perf_counter() - collected, 1),
               "workers": workers, "git_revision": revision, "history": history,
               "config": to_dict(config)}
    save_pocket_net(out / "pockets.safetensors", net, config.small_area_m2,
                    provenance={"git_revision": revision, "config": to_dict(config),
                                "validation": history[-1]})
    write_text_atomic(out / "fit.json", json.dumps(summary, indent=1))
    return {k: summary[k] for k in ("samples", "small_share", "collect_s", "fit_s")} | {
        "validation": history[-1], "weights": str(out / "pockets.safetensors")}
