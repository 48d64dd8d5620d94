"""Training the map predictor (:mod:`mjexplore.mapping.prediction`) by supervision.

**Data.** Episodes on generated layouts (the config's families and sizes, the grid world by
default) are driven by a rule drawn per episode from ``explorers``; at a ``random_share`` of
the decisions the robot takes a random reachable frontier instead, so the partial maps vary
beyond what one rule reaches. At a ``record_share`` of the decisions the partial map's coarse
channels are kept, and the layout's coarse truth once per episode. Each episode is a shard
``data/episode_NNNNN.npz`` (plain arrays, read without pickle), written whole or not at all:
an interrupted collection resumes at the first shard missing. Every ``validation_every``-th
episode is held out.

**Fit.** A fresh :class:`~mjexplore.mapping.prediction.MapPredictorNet` is fitted to the free
share (free where at least half the block is) of the cells the partial map leaves unknown,
by binary cross-entropy, on random ``crop`` x ``crop`` windows of the maps, each turned and
mirrored at random (the eight symmetries of the square). A checkpoint after every epoch
(``checkpoint.pt``: weights, optimiser, epoch and random state; read with
``torch.load(weights_only=True)``) lets an interrupted fit resume; TensorBoard logs go to
``tb/``.

**Quality.** On the held-out episodes' whole maps, the learned predictor beside the three
non-learned ones (:data:`~mjexplore.mapping.prediction.BASELINES`), by
:func:`~mjexplore.mapping.prediction.prediction_quality`.

``mjexplore train-predictor --config training/predictor.yaml --out runs/train/predictor``
writes the model folder: ``predictor.safetensors``, ``config.yaml``, ``quality.json`` and
``README.md`` (its card).
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import multiprocessing as mp
import time
from pathlib import Path
from typing import Any

import numpy as np

from mjexplore.config import load_yaml_config, to_dict
from mjexplore.envs.exploration import EnvConfig
from mjexplore.episode.explorer import ExplorationState, Explorer
from mjexplore.errors import UserInputError
from mjexplore.io.atomic import refuse_foreign_files, write_bytes_atomic, write_text_atomic
from mjexplore.io.progress import Progress
from mjexplore.io.provenance import file_sha256, git_revision
from mjexplore.learning.pocket_training import episode_layout

log = logging.getLogger(__name__)

SHARD = "episode_{:05d}.npz"


@dataclasses.dataclass(frozen=True, kw_only=True)
class PredictorTrainingConfig:
    """Data collection and fit of the map predictor.

    Attributes:
        env: Layouts (``procedural``) and episode settings of the collection episodes, as in
            a training config.
        episodes: Collection episodes; episode ``i`` resets the env with seed
            ``data_seed + i``.
        seed: The seed of the fit (the network's initial weights, the windows drawn), and of
            the data set when ``data_seed`` is None.
        data_seed: The seed of the data set: the first episode's layout seed and the seed of
            the episodes' random choices; None: ``seed``. Training seeds of one recipe that
            share it fit the same maps (separate seeds of the layouts would overlap: episode
            ``i`` of one is episode ``i - 1`` of the next).
        explorers: Rules that drive the episodes, one drawn per episode.
        random_share: Share of the decisions that take a random reachable frontier.
        record_share: Share of the decisions whose partial map is kept.
        validation_every: Every this many episodes one is held out.
        width: Channels of the U-Net's first level.
        dropout: Bottleneck dropout (Monte Carlo dropout at prediction).
        crop: Side of the training windows, coarse cells (a multiple of 8).
        epochs: Passes over the training maps.
        batch_size: Windows per gradient step.
        learning_rate: Adam's step size.
        threads: Torch threads of the fit.
    """

    env: EnvConfig
    episodes: int = 400
    seed: int = 0
    data_seed: int | None = None
    explorers: tuple[str, ...] = ("nearest", "pocket_nearest", "frontier_tsp")
    random_share: float = 0.3
    record_share: float = 0.3
    validation_every: int = 10
    width: int = 16
    dropout: float = 0.1
    crop: int = 96
    epochs: int = 8
    batch_size: int = 16
    learning_rate: float = 1e-3
    threads: int = 2

    def __post_init__(self) -> None:
        if self.env.procedural is None:
            raise UserInputError("env.procedural must name the generated layouts to learn "
                                 "from (families, width, height).")
        if self.episodes < 2 or self.validation_every < 2:
            raise UserInputError("episodes and validation_every must be >= 2.")
        if not (0 <= self.random_share <= 1 and 0 < self.record_share <= 1):
            raise UserInputError("random_share must be in [0, 1], record_share in (0, 1].")
        if self.crop < 8 or self.crop % 8 or self.width < 1 or not 0 <= self.dropout < 1:
            raise UserInputError("crop must be a multiple of 8 (>= 8), width >= 1, dropout "
                                 "in [0, 1).")
        if self.epochs < 1 or self.batch_size < 1 or self.learning_rate <= 0:
            raise UserInputError("epochs and batch_size must be >= 1, learning_rate > 0.")
        if not self.explorers:
            raise UserInputError("explorers must name at least one rule (e.g. nearest).")


def load_predictor_config(path: str | Path) -> PredictorTrainingConfig:
    """Reads a predictor-training YAML (see training/predictor.yaml).

    Raises:
        UserInputError: unreadable, or an unknown explorer.
    """
    from mjexplore.explorers import explorer_class

    config = load_yaml_config(PredictorTrainingConfig, path)
    for name in config.explorers:
        explorer_class(name)
    return config


class _Recorder:
    """Drives with ``base``, a random reachable frontier at a share of the decisions, and
    keeps the coarse channels of the map at a share of them."""

    name = "map_recorder"

    def __init__(self, base: Explorer, rng: np.random.Generator, random_share: float,
                 record_share: float) -> None:
        self.base, self.rng = base, rng
        self.random_share, self.record_share = random_share, record_share
        self.inputs: list[np.ndarray] = []

    def reset(self, rng: np.random.Generator) -> None:
        self.base.reset(rng)

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        from mjexplore.mapping.prediction import coarse_channels

        if self.rng.random() < self.record_share:
            self.inputs.append(coarse_channels(state.grid))
        if state.frontiers and self.rng.random() < self.random_share:
            reachable = np.flatnonzero(np.isfinite(state.frontier_distances()))
            if len(reachable):
                return state.frontiers[int(self.rng.choice(reachable))].goal
        return self.base.select_goal(state)


def record_episode(config: PredictorTrainingConfig, index: int) -> bytes:
    """Runs collection episode ``index``; its shard (an ``.npz`` of the partial maps it
    kept, the truth, the scene and the rule that drove)."""
    import torch

    from mjexplore.episode import Episode
    from mjexplore.explorers import make_explorer
    from mjexplore.mapping.prediction import coarse_truth

    torch.set_num_threads(1)
    data_seed = config.seed if config.data_seed is None else config.data_seed
    scene, sim_seed, episode = episode_layout(config.env, data_seed + index)
    rng = np.random.default_rng([data_seed, index])
    rule = config.explorers[int(rng.integers(len(config.explorers)))]
    recorder = _Recorder(make_explorer(rule), rng, config.random_share, config.record_share)
    Episode(scene, recorder, sim_seed, episode).run()
    truth = coarse_truth(scene.ground_truth)
    inputs = (np.stack(recorder.inputs) if recorder.inputs
              else np.zeros((0, 3, *truth.shape), np.uint8))
    buffer = io.BytesIO()
    np.savez_compressed(buffer, inputs=inputs, truth=truth, scene=np.array(str(scene.xml.parent)),
                        rule=np.array(rule))
    return buffer.getvalue()


def collect_episode(config: PredictorTrainingConfig, index: int, folder: Path) -> None:
    """Runs collection episode ``index`` and writes its shard into ``folder``."""
    write_bytes_atomic(folder / SHARD.format(index), record_episode(config, index))


def _collect_job(args: tuple[PredictorTrainingConfig, int, Path]) -> None:
    collect_episode(*args)


def collect(config: PredictorTrainingConfig, folder: Path, workers: int = 1,
            progress: Progress | None = None, ray_address: str | None = None) -> None:
    """Writes the shards of the episodes ``folder`` lacks: in ``workers`` processes, or as
    Ray tasks on the cluster at ``ray_address`` ('local': a Ray instance on this machine
    with ``workers`` CPUs), whose shards come back as data.

    Raises:
        UserInputError: no Ray cluster at ``ray_address``; an episode that failed there.
    """
    from mjexplore.episode.workers import init_episode_worker

    folder.mkdir(parents=True, exist_ok=True)
    todo = [i for i in range(config.episodes) if not (folder / SHARD.format(i)).exists()]
    if progress is not None:
        progress.update(config.episodes - len(todo))
    if ray_address is not None and todo:
        import ray

        from mjexplore.io.ray_cluster import connect, map_unordered

        joined = connect(ray_address, local_cpus=workers)
        try:
            for k, shard, error in map_unordered(record_episode, [(config, i) for i in todo],
                                                 initializer=init_episode_worker):
                if error is not None:
                    raise UserInputError(
                        f"collection episode {todo[k]} failed on Ray ({type(error).__name__}: "
                        f"{error}); the shards written are kept: run the same command again "
                        "to resume.") from None
                write_bytes_atomic(folder / SHARD.format(todo[k]), shard)
                if progress is not None:
                    progress.update()
        finally:
            if joined:
                ray.shutdown()
        return
    jobs = [(config, i, folder) for i in todo]
    if workers > 1 and len(jobs) > 1:
        with mp.get_context("spawn").Pool(workers, initializer=init_episode_worker) as pool:
            for _ in pool.imap_unordered(_collect_job, jobs):
                if progress is not None:
                    progress.update()
    else:
        for job in jobs:
            _collect_job(job)
            if progress is not None:
                progress.update()


def load_shards(config: PredictorTrainingConfig, folder: Path
                ) -> tuple[list[dict[str, np.ndarray]], list[dict[str, np.ndarray]]]:
    """The training and the held-out episodes' maps (``inputs``, ``truth``), in order."""
    train: list[dict[str, np.ndarray]] = []
    held: list[dict[str, np.ndarray]] = []
    for i in range(config.episodes):
        with np.load(folder / SHARD.format(i), allow_pickle=False) as shard:
            part = {"inputs": shard["inputs"], "truth": shard["truth"]}
        if len(part["inputs"]):
            (held if i % config.validation_every == 0 else train).append(part)
    if not train or not held:
        raise UserInputError("the predictor needs recorded maps in both the training and the "
                             "held-out episodes: collect more episodes (episodes, "
                             "record_share).")
    return train, held


def _window(part: dict[str, np.ndarray], k: int, crop: int, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray]:
    """A random ``crop`` window of map ``k`` of an episode (zeros past its edge: outside),
    turned and mirrored at random: (3, crop, crop) input, (crop, crop) truth."""
    channels, truth = part["inputs"][k], part["truth"]
    rows, cols = truth.shape
    r0 = int(rng.integers(min(0, rows - crop), max(rows - crop, 0) + 1))
    c0 = int(rng.integers(min(0, cols - crop), max(cols - crop, 0) + 1))
    x = np.zeros((3, crop, crop), np.uint8)
    y = np.zeros((crop, crop), np.uint8)
    src_r, src_c = slice(max(r0, 0), min(r0 + crop, rows)), slice(max(c0, 0),
                                                                   min(c0 + crop, cols))
    dst_r = slice(src_r.start - r0, src_r.stop - r0)
    dst_c = slice(src_c.start - c0, src_c.stop - c0)
    x[:, dst_r, dst_c] = channels[:, src_r, src_c]
    y[dst_r, dst_c] = truth[src_r, src_c]
    turns, flip = int(rng.integers(4)), bool(rng.integers(2))
    x, y = np.rot90(x, turns, (1, 2)), np.rot90(y, turns)
    if flip:
        x, y = x[:, :, ::-1], y[:, ::-1]
    return np.ascontiguousarray(x), np.ascontiguousarray(y)


def masked_bce(logits, channels, truth):
    """Binary cross-entropy of the free logits on the unknown cells of a batch (mean over
    them; 0 when there are none)."""
    import torch

    known = channels[:, 0].to(torch.int32) + channels[:, 1]
    unknown = (channels[:, 2] > 0) & (known < 128)
    target = (truth >= 128).to(torch.float32)
    loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, target,
                                                                reduction="none")
    return (loss * unknown).sum() / unknown.sum().clamp(min=1)


def predict_maps(net, held: list[dict[str, np.ndarray]]) -> list[np.ndarray]:
    """The net's free probability for every held-out map (whole, one pass)."""
    from mjexplore.mapping.prediction import free_probability

    net.eval()
    return [free_probability(net, channels) for part in held for channels in part["inputs"]]


def quality_table(net, held: list[dict[str, np.ndarray]]
                  ) -> dict[str, dict[str, float | None]]:
    """:func:`~mjexplore.mapping.prediction.prediction_quality` of the net and of each
    non-learned predictor on the held-out maps."""
    from mjexplore.mapping.prediction import BASELINES, prediction_quality

    maps = [(channels, part["truth"]) for part in held for channels in part["inputs"]]
    table = {"learned": prediction_quality(
        (p, c, t) for p, (c, t) in zip(predict_maps(net, held), maps))}
    for name, predict in BASELINES.items():
        table[name] = prediction_quality((predict(c), c, t) for c, t in maps)
    return table


def steps_per_epoch(config: PredictorTrainingConfig, train: list[dict[str, np.ndarray]]
                    ) -> int:
    """Gradient steps in one pass over the training maps."""
    return -(-sum(len(part["inputs"]) for part in train) // config.batch_size)


def fit(config: PredictorTrainingConfig, train: list[dict[str, np.ndarray]],
        held: list[dict[str, np.ndarray]], out: Path, progress: Progress | None = None):
    """Fits (or resumes fitting) the net; returns it and the per-epoch history.
    ``progress`` counts the gradient steps."""
    import torch
    from torch.utils.tensorboard import SummaryWriter

    from mjexplore.mapping.prediction import MapPredictorNet

    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    net = MapPredictorNet(config.width, config.dropout)
    optimiser = torch.optim.Adam(net.parameters(), lr=config.learning_rate)
    rng = np.random.default_rng(config.seed)
    history: list[dict[str, Any]] = []
    start = 0
    checkpoint = out / "checkpoint.pt"
    if checkpoint.exists():
        state = torch.load(checkpoint, weights_only=True)
        net.load_state_dict(state["net"])
        optimiser.load_state_dict(state["optimiser"])
        rng.bit_generator.state = json.loads(state["rng"])
        torch.set_rng_state(state["torch_rng"])
        history, start = json.loads(state["history"]), int(state["epoch"]) + 1
    samples = [(e, k) for e, part in enumerate(train) for k in range(len(part["inputs"]))]
    if progress is not None:
        progress.update(start * steps_per_epoch(config, train))
    with SummaryWriter(str(out / "tb")) as writer:
        for epoch in range(start, config.epochs):
            net.train()
            order = rng.permutation(len(samples))
            total, steps = 0.0, 0
            for b in range(0, len(order), config.batch_size):
                windows = [_window(train[samples[i][0]], samples[i][1], config.crop, rng)
                           for i in order[b:b + config.batch_size]]
                x = torch.from_numpy(np.stack([w[0] for w in windows]))
                y = torch.from_numpy(np.stack([w[1] for w in windows]))
                loss = masked_bce(net(x), x, y)
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                total, steps = total + loss.item(), steps + 1
                if progress is not None:
                    progress.update(detail=f"epoch {epoch + 1}, training BCE "
                                           f"{total / steps:.3f}")
            figures = quality_table(net, held)["learned"]
            figures.update(epoch=epoch, train_bce=round(total / max(steps, 1), 4))
            history.append(figures)
            for key in ("train_bce", "bce", "accuracy", "iou_free", "ece"):
                writer.add_scalar(f"predictor/{key}", figures[key], epoch)
            log.info("predictor epoch %d: %s", epoch, figures)
            state = {"net": net.state_dict(), "optimiser": optimiser.state_dict(),
                     "epoch": epoch, "rng": json.dumps(rng.bit_generator.state),
                     "torch_rng": torch.get_rng_state(), "history": json.dumps(history)}
            tmp = checkpoint.with_suffix(".tmp")
            torch.save(state, tmp)
            tmp.replace(checkpoint)
            if progress is not None:
                progress.detail(f"epoch {epoch + 1}, held-out IoU {figures['iou_free']:.3f}")
    return net, history


def _card(config: PredictorTrainingConfig, quality: dict, summary: dict) -> str:
    """The model folder's README.md."""
    proc = config.env.procedural
    assert proc is not None  # PredictorTrainingConfig requires it.
    facts = [
        ("trained", f"{summary['train_maps']:,} partial maps of {summary['train_episodes']} "
                    f"episodes, {config.epochs} epochs, at revision `{summary['git_revision']}`"),
        ("layouts", f"generated: {', '.join(proc.families)}; width {proc.width} m, height "
                    f"{proc.height} m; episodes driven by {', '.join(config.explorers)} with "
                    f"{config.random_share:.0%} random frontier choices"),
        ("held out", f"{summary['held_maps']:,} maps of {summary['held_episodes']} episodes "
                     f"(every {config.validation_every}th)"),
        ("weights", f"`predictor.safetensors`, sha256 `{summary['weights_sha256']}`"),
        ("recipe", "`config.yaml`")]
    learned = quality["learned"]
    return "\n".join([
        "# Map predictor", "",
        f"A U-Net ({summary['parameters']:,} parameters, {config.width} channels at the first "
        f"level, Monte Carlo dropout {config.dropout}) that predicts, per {summary['cell_m']} m "
        "cell of a partial occupancy map, the probability that the cell is free "
        "(`mjexplore/mapping/prediction.py`).", "",
        "| | |", "|---|---|", *(f"| {k} | {v} |" for k, v in facts), "",
        f"**Quality on the held-out maps' unknown cells** ({learned['cells']:,} cells, of which "
        f"{learned['free_share']:.1%} free; BCE in nats, accuracy at 0.5, IoU of the free "
        "space, expected calibration error):", "",
        "| predictor | BCE | accuracy | IoU free | ECE |", "|---|---|---|---|---|",
        *(f"| {name} | {q['bce']:.3f} | {q['accuracy']:.3f} | {q['iou_free']:.3f} | "
          f"{q['ece']:.3f} |" for name, q in quality.items()), ""])


def train_predictor(config: PredictorTrainingConfig, out: str | Path, workers: int = 1,
                    progress: bool = False, ray_address: str | None = None) -> dict[str, Any]:
    """Collects, fits and writes the model folder ``out``; returns its summary. A folder
    of an interrupted run with the same settings is resumed (the shards it has are kept,
    the fit goes on from its last epoch). ``ray_address``: collect on Ray (see
    :func:`collect`).

    Raises:
        UserInputError: ``out`` holds a run with other settings, or other files.
    """
    import yaml

    from mjexplore.mapping.prediction import CELL_M, save_map_predictor

    out = Path(out)
    revision = git_revision()
    started = time.perf_counter()
    recipe = yaml.safe_dump(to_dict(config), sort_keys=False)
    saved = out / "config.yaml"
    if saved.exists() and saved.read_text() != recipe:
        raise UserInputError(f"{str(out)!r} holds a predictor run with other settings "
                             f"({saved}): give another --out, or the same config to resume.")
    refuse_foreign_files(out, ("config.yaml", "data", "checkpoint.pt", "tb",
                               "predictor.safetensors", "quality.json", "README.md", ".*.tmp"),
                         "a train-predictor run")
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(saved, recipe)
    with Progress(config.episodes, "train-predictor", "episodes", enabled=progress,
                  phase="collecting") as shown:
        collect(config, out / "data", workers, shown, ray_address)
    collected = time.perf_counter()
    train, held = load_shards(config, out / "data")
    with Progress(config.epochs * steps_per_epoch(config, train), "train-predictor", "steps",
                  enabled=progress,
                  phase="fitting") as shown:
        net, history = fit(config, train, held, out, shown)
    quality = quality_table(net, held)
    save_map_predictor(out / "predictor.safetensors", net,
                       provenance={"git_revision": revision, "config": to_dict(config),
                                   "quality": quality["learned"]})
    summary = {"parameters": sum(p.numel() for p in net.parameters()), "cell_m": CELL_M,
               "train_episodes": len(train), "held_episodes": len(held),
               "train_maps": sum(len(p["inputs"]) for p in train),
               "held_maps": sum(len(p["inputs"]) for p in held),
               "collect_s": round(collected - started, 1),
               "fit_s": round(time.perf_counter() - collected, 1), "workers": workers,
               "git_revision": revision,
               "weights_sha256": file_sha256(out / "predictor.safetensors")}
    write_text_atomic(out / "quality.json", json.dumps(
        {"quality": quality, "history": history, **summary}, indent=1) + "\n")
    write_text_atomic(out / "README.md", _card(config, quality, summary))
    return {**summary, "quality": quality}
