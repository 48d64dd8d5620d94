"""The map predictor: its input and target, the non-learned predictors, the quality scores,
its weights file, and train-predictor end to end (collect, fit, resume, refuse)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.mapping.prediction import (
    MapPredictor,
    MapPredictorNet,
    coarse_channels,
    coarse_truth,
    free_probability,
    inpainted,
    prediction_quality,
    save_map_predictor,
    unknown_as_free,
    unknown_as_occupied,
    unknown_cells,
    unknown_within,
)
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "models" / "map_predictor" / "predictor.safetensors"


def _corridor() -> tuple[GridMap, GridMap]:
    """A 4 x 2 m map (0.05 m cells) of wall with a 0.8 m corridor across it (rows 14-29),
    and the same map with its middle metre unknown."""
    data = np.full((40, 80), OCCUPIED, np.int8)
    data[14:30, :] = FREE
    truth = GridMap(data, 0.05)
    partial = data.copy()
    partial[:, 30:50] = UNKNOWN
    return truth, GridMap(partial, 0.05)


def test_coarse_channels_and_truth_are_block_shares():
    truth, partial = _corridor()
    channels = coarse_channels(partial)
    assert channels.shape == (3, 10, 20) and channels.dtype == np.uint8
    assert channels[0, 4, 0] == 255 and channels[1, 0, 0] == 255  # Free corridor, wall.
    assert channels[0, 3, 0] == 128 and channels[1, 3, 0] == 128  # Rows 12-15: half wall.
    assert (channels[:2, :, 8:12] == 0).all() and (channels[2] == 255).all()
    target = coarse_truth(truth)
    assert target.shape == (10, 20) and (target[4:7, 10] == 255).all() and target[3, 10] == 128
    assert unknown_cells(channels)[:, 8:12].all() and not unknown_cells(channels)[:, :7].any()


def test_coarse_cells_need_a_resolution_that_divides_them():
    grid = GridMap(np.zeros((30, 30), np.int8), 0.03)
    with pytest.raises(UserInputError, match="resolution"):
        coarse_channels(grid)


def test_baselines_and_the_quality_scores():
    truth, partial = _corridor()
    channels, target = coarse_channels(partial), coarse_truth(truth)
    perfect = np.where(target >= 128, 1.0, 0.0)
    best = prediction_quality([(perfect, channels, target)])
    assert best["accuracy"] == 1.0 and best["iou_free"] == 1.0 and best["bce"] < 1e-3
    assert best["ece"] < 1e-3 and best["cells"] == 40
    free = prediction_quality([(unknown_as_free(channels), channels, target)])
    assert free["accuracy"] == pytest.approx(free["free_share"])
    none = prediction_quality([(unknown_as_occupied(channels), channels, target)])
    assert none["iou_free"] == 0.0 and none["accuracy"] == pytest.approx(1 - none["free_share"])
    # Inpainting carries the corridor on through the gap and the walls beside it.
    filled = inpainted(channels)
    assert (filled[4:6, 8:12] > 0.5).all() and (filled[0, 8:12] < 0.5).all()
    assert prediction_quality([(filled, channels, target)])["accuracy"] > free["accuracy"]
    # The confident cells: every cell of a 0/1 prediction, none of a 0.5 one; a wrong
    # confident cell counts against their accuracy, an unsure one not.
    assert best["confident_share"] == 1.0 and best["confident_accuracy"] == 1.0
    unsure = prediction_quality([(np.full(target.shape, 0.5), channels, target)])
    assert unsure["confident_share"] == 0.0 and unsure["confident_accuracy"] is None
    mixed = np.where(target >= 128, 0.6, 0.9)  # Walls called free, free cells unsure.
    q = prediction_quality([(mixed, channels, target)])
    assert q["confident_share"] == pytest.approx(1 - q["free_share"])
    assert q["confident_accuracy"] == 0.0


def test_scoring_near_the_known_cells_keeps_the_unknown_cells_within_the_distance():
    """The unknown band (coarse columns 8-11) lies between known columns 7 and 12: within
    0.2 m (one cell) keeps its two edge columns, within 0.4 m all of it."""
    truth, partial = _corridor()
    channels, target = coarse_channels(partial), coarse_truth(truth)
    near = unknown_within(channels, 0.2)
    assert near[:, [8, 11]].all() and not near[:, 9:11].any() and not near[:, :8].any()
    assert (unknown_within(channels, 0.4) == unknown_cells(channels)).all()
    p = np.where(np.arange(channels.shape[2])[None, :] < 10, 1.0, 0.0) * np.ones(
        channels.shape[1:])
    assert prediction_quality([(p, channels, target)], within_m=0.2)["cells"] == near.sum()


def test_weights_round_trip_and_monte_carlo_dropout(tmp_path):
    torch.manual_seed(0)
    net = MapPredictorNet(width=4, dropout=0.3)
    save_map_predictor(tmp_path / "p.safetensors", net, provenance={"test": 1})
    predictor = MapPredictor(tmp_path / "p.safetensors")
    _, partial = _corridor()
    channels = coarse_channels(partial)
    p, spread = predictor.predict_channels(channels)
    net.eval()
    with torch.no_grad():
        x = torch.zeros((1, 3, 16, 24), dtype=torch.uint8)
        x[0, :, :10, :20] = torch.from_numpy(channels)
        expected = torch.sigmoid(net(x))[0, :10, :20].numpy()
    np.testing.assert_allclose(p, expected, atol=1e-6)
    assert p.shape == (10, 20) and not spread.any()
    mean, std = predictor.predict_channels(channels, samples=8, seed=3)
    again, _ = predictor.predict_channels(channels, samples=8, seed=3)
    np.testing.assert_array_equal(mean, again)
    assert std.max() > 0
    (tmp_path / "bad.safetensors").write_bytes(b"not a tensor file")
    with pytest.raises(UserInputError):
        MapPredictor(tmp_path / "bad.safetensors")


@pytest.mark.slow
def test_train_predictor_collects_fits_resumes_and_refuses(tmp_path):
    config = tmp_path / "predictor.yaml"
    config.write_text(
        "episodes: 2\nvalidation_every: 2\nepochs: 1\nwidth: 4\ncrop: 32\nbatch_size: 4\n"
        "record_share: 0.5\nexplorers: [nearest]\nthreads: 1\n"
        "env:\n  procedural: {families: [rooms], width: [12.0, 12.0], height: [10.0, 10.0]}\n"
        "  episode:\n    max_time: 300.0\n    sim: {dynamics: grid}\n")
    out = tmp_path / "model"
    assert main(["train-predictor", "--config", str(config), "--out", str(out),
                 "--workers", "1", "--no-progress"]) == 0
    for name in ("predictor.safetensors", "README.md", "quality.json", "config.yaml",
                 "checkpoint.pt", "data/episode_00000.npz", "data/episode_00001.npz"):
        assert (out / name).exists(), name
    quality = json.loads((out / "quality.json").read_text())["quality"]
    assert set(quality) == {"learned", "unknown_as_free", "unknown_as_occupied", "inpainting"}
    assert "inpainting" in (out / "README.md").read_text()
    weights = load_file(out / "predictor.safetensors")
    shard = (out / "data/episode_00001.npz").stat().st_mtime_ns
    # Resumed with the same settings: the shards are kept and the finished fit is not redone.
    assert main(["train-predictor", "--config", str(config), "--out", str(out),
                 "--workers", "1", "--no-progress"]) == 0
    assert (out / "data/episode_00001.npz").stat().st_mtime_ns == shard
    again = load_file(out / "predictor.safetensors")
    assert all(torch.equal(again[k], v) for k, v in weights.items())
    # Other settings into the same folder: refused, nothing changed.
    assert main(["train-predictor", "--config", str(config), "--out", str(out),
                 "--epochs", "2", "--workers", "1", "--no-progress"]) == 2
    assert all(torch.equal(load_file(out / "predictor.safetensors")[k], v)
               for k, v in weights.items())


def _held_out_maps() -> list[tuple[np.ndarray, np.ndarray]]:
    """Partial maps (coarse channels) and truths at the decisions of nearest-frontier on three
    generated layouts with test generator seeds (apart from training and every choice)."""
    from mjexplore.envs.exploration import TEST_SEED_BASE, heldout_scenes
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.episode.nearest import NearestFrontier
    from mjexplore.learning.predictor_training import load_predictor_config
    from mjexplore.scenes.scene import load_scene_files
    from mjexplore.sim.simulator import SimConfig

    proc = load_predictor_config(REPO / "training" / "predictor.yaml").env.procedural
    maps = []

    class _Keep(NearestFrontier):
        def select_goal(self, state):
            self.kept.append(coarse_channels(state.grid))
            return super().select_goal(state)

    for folder in heldout_scenes(proc, 3, base=TEST_SEED_BASE):
        scene = load_scene_files(folder)
        explorer = _Keep()
        explorer.kept = []
        Episode(scene, explorer, 0, EpisodeConfig(max_time=1800.0,
                                                  sim=SimConfig(dynamics="grid"))).run()
        truth = coarse_truth(scene.ground_truth)
        maps += [(channels, truth) for channels in explorer.kept[::5]]
    return maps


@pytest.mark.skipif(not SHIPPED.is_file(), reason="no shipped map predictor")
def test_the_shipped_predictor_beats_inpainting_and_an_untrained_one_does_not():
    maps = _held_out_maps()
    assert len(maps) >= 10

    def quality(predict):
        return prediction_quality((predict(c), c, t) for c, t in maps)

    shipped = quality(MapPredictor(SHIPPED))
    inpainting = quality(inpainted)
    torch.manual_seed(0)
    untrained_net = MapPredictorNet().eval()

    random = quality(lambda channels: free_probability(untrained_net, channels))
    # Accuracy and cross-entropy; the free space's IoU favours calling every unknown cell
    # free where most are (inpainting nearly does), and the two tie on these layouts.
    assert shipped["accuracy"] > inpainting["accuracy"] + 0.03, (shipped, inpainting)
    assert shipped["bce"] < min(inpainting["bce"], random["bce"]), (shipped, random)
    assert random["accuracy"] <= inpainting["accuracy"], (random, inpainting)


def test_training_seeds_that_share_a_data_seed_record_the_same_maps(tmp_path):
    import dataclasses
    import io

    from mjexplore.learning.predictor_training import load_predictor_config, record_episode

    (tmp_path / "p.yaml").write_text(
        "episodes: 2\nvalidation_every: 2\nrecord_share: 0.5\nexplorers: [nearest]\n"
        "env:\n  procedural: {families: [rooms], width: [12.0, 12.0], height: [10.0, 10.0]}\n"
        "  episode:\n    max_time: 120.0\n    sim: {dynamics: grid}\n")
    base = load_predictor_config(tmp_path / "p.yaml")

    def maps(config):
        with np.load(io.BytesIO(record_episode(config, 0))) as shard:
            return shard["inputs"], shard["truth"]

    first = maps(base)
    same_data = maps(dataclasses.replace(base, seed=1, data_seed=0))
    other_data = maps(dataclasses.replace(base, seed=1))
    assert len(first[0]) > 0
    np.testing.assert_array_equal(first[0], same_data[0])
    np.testing.assert_array_equal(first[1], same_data[1])
    assert first[1].shape != other_data[1].shape or not np.array_equal(first[1], other_data[1])
