"""The frontier-pocket predictor: patches, true pockets, the weights file, its training and
what the shipped predictor knows on layouts it never saw."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mjexplore.errors import UserInputError
from mjexplore.maps import GridMap
from mjexplore.topology.frontiers import find_frontiers
from mjexplore.topology.pockets import (
    PATCH_CELLS,
    PocketNet,
    PocketPredictor,
    frontier_lengths,
    frontier_patches,
    frontier_windows,
    pocket_areas,
    pocket_predictor,
    save_pocket_net,
)

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "training" / "pockets.safetensors"


def _room(resolution: float) -> tuple[GridMap, GridMap]:
    """A 6 x 4 m room with a 0.5 m wide, 0.25 m deep alcove in its north wall (ground
    truth) and a partial map that knows the room's west half but not the alcove."""
    rows, cols = int(round(4.6 / resolution)), int(round(6.6 / resolution))
    truth = np.full((rows, cols), 100, np.int8)
    w = int(round(0.3 / resolution))
    truth[w:rows - w, w:cols - w] = 0
    a0, a1 = int(round(1.0 / resolution)), int(round(1.5 / resolution))
    truth[rows - w:rows - w + int(round(0.25 / resolution)), a0:a1] = 0
    known = np.full_like(truth, -1)
    half = cols // 2
    known[:, :half] = truth[:, :half]
    known[rows - w:, a0:a1] = -1  # The alcove is not seen yet.
    return GridMap(known, resolution), GridMap(truth, resolution)


def test_patches_are_metric_whatever_the_map_resolution():
    fine_map, _ = _room(0.05)
    coarse_map, _ = _room(0.1)
    fine = frontier_patches(fine_map, find_frontiers(fine_map))
    coarse = frontier_patches(coarse_map, find_frontiers(coarse_map))
    assert fine.shape[1:] == coarse.shape[1:] == (3, PATCH_CELLS, PATCH_CELLS)
    # The long frontier down the room's middle: the same free and occupied layout.
    big_fine = fine[np.argmax(fine[:, 2].sum(axis=(1, 2)))].astype(float)
    big_coarse = coarse[np.argmax(coarse[:, 2].sum(axis=(1, 2)))].astype(float)
    assert np.abs(big_fine[:2] - big_coarse[:2]).mean() < 0.1 * 255


def test_patch_channels_hold_free_occupied_and_the_frontier_itself():
    grid, _ = _room(0.1)
    frontiers = find_frontiers(grid)
    patches = frontier_patches(grid, frontiers)
    for f, patch in zip(frontiers, patches):
        assert patch[2].sum() == pytest.approx(255 * min(f.size, PATCH_CELLS ** 2), rel=0.05)
        # Free and occupied shares never exceed the whole cell; outside the map is unknown.
        assert (patch[0].astype(int) + patch[1] <= 255).all()
    assert frontier_lengths(grid, frontiers) == pytest.approx(
        [f.size * 0.1 for f in frontiers])


def test_pocket_areas_are_the_unseen_free_space_behind_each_frontier():
    grid, truth = _room(0.05)
    frontiers = find_frontiers(grid)
    areas = pocket_areas(grid, truth, frontiers)
    east_half = float(((truth.data == 0) & (grid.data < 0)).sum()) * 0.05 ** 2 - 0.125
    assert areas.max() == pytest.approx(east_half, rel=1e-6)
    assert areas.min() == pytest.approx(0.125, rel=1e-6)  # The alcove's frontier.


def test_memo_predicts_only_frontiers_whose_surroundings_changed(monkeypatch):
    room, _ = _room(0.05)  # Twice, 14 m apart: farther than a window's side.
    gap = np.full((room.shape[0], 280), -1, np.int8)
    grid = GridMap(np.hstack([room.data, gap, room.data[::-1]]), 0.05)
    frontiers = find_frontiers(grid)
    predictor = pocket_predictor(SHIPPED)
    batches = []
    predict = predictor._predict
    monkeypatch.setattr(predictor, "_predict",
                        lambda patches, lengths: batches.append(len(patches))
                        or predict(patches, lengths))
    memo = {}
    first = predictor.small_probability(grid, frontiers, memo)
    assert first == pytest.approx(predictor.small_probability(grid, frontiers), abs=1e-6)
    assert batches == [len(frontiers), len(frontiers)] and len(memo) == len(frontiers)
    # Nothing changed: read back, bit for bit.
    assert np.array_equal(predictor.small_probability(grid, frontiers, memo), first)
    assert batches == [len(frontiers), len(frontiers)]
    # A free cell beside an alcove's frontier turns to wall: the frontiers whose window
    # holds it (not those of the other room) are predicted again, and only theirs move.
    alcove = int(np.argmin([f.size for f in frontiers]))
    seen = grid.data.copy()
    free = np.argwhere(seen == 0)
    r, c = free[np.argmin(np.abs(free - frontiers[alcove].cells[0]).sum(axis=1))]
    seen[r, c] = 100
    changed = GridMap(seen, 0.05)
    moved = [not np.array_equal(a[0], b[0]) for a, b in zip(
        frontier_windows(grid, frontiers), frontier_windows(changed, frontiers))]
    assert moved[alcove] and not all(moved)
    after = predictor.small_probability(changed, frontiers, memo)
    assert batches[-1] == sum(moved) and len(memo) == len(frontiers) + sum(moved)
    assert np.array_equal(after[~np.array(moved)], first[~np.array(moved)])


def test_weights_file_round_trip_and_refusals(tmp_path):
    net = PocketNet()
    path = tmp_path / "pockets.safetensors"
    save_pocket_net(path, net, 0.5, provenance={"note": "test"})
    grid, _ = _room(0.1)
    frontiers = find_frontiers(grid)
    loaded = PocketPredictor(path)
    assert loaded.small_area_m2 == 0.5 and loaded.provenance == {"note": "test"}
    p = loaded.small_probability(grid, frontiers)
    assert p.shape == (len(frontiers),) and ((p > 0) & (p < 1)).all()
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a safetensors file")
    with pytest.raises(UserInputError, match="safetensors"):
        PocketPredictor(bad)
    with pytest.raises(UserInputError, match="sha256"):
        pocket_predictor(path, sha256="0" * 16)
    import torch
    from safetensors.torch import save

    from mjexplore.topology.pockets import FORMAT

    damaged = tmp_path / "damaged.safetensors"  # Our format tag, no patch layout or area.
    damaged.write_bytes(save({"x": torch.zeros(1)}, metadata={"format": FORMAT}))
    with pytest.raises(UserInputError, match="not a pocket predictor"):
        PocketPredictor(damaged)


@pytest.mark.slow
def test_training_writes_weights_and_validation_figures(tmp_path):
    from mjexplore.learning.pocket_training import load_pocket_config, train_pockets

    config = load_pocket_config(ROOT / "training" / "pockets.yaml")
    proc = dataclasses.replace(config.env.procedural, width=(12.0, 14.0), height=(10.0, 12.0))
    config = dataclasses.replace(config, env=dataclasses.replace(config.env, procedural=proc),
                                 episodes=4, validation_every=2, epochs=1)
    summary = train_pockets(config, tmp_path, workers=1)
    assert summary["samples"] > 50
    assert 0.0 <= summary["validation"]["accuracy"] <= 1.0
    predictor = PocketPredictor(tmp_path / "pockets.safetensors")
    assert predictor.provenance["config"]["episodes"] == 4
    assert (tmp_path / "fit.json").is_file()


@pytest.mark.slow
def test_shipped_predictor_tells_small_pockets_on_unseen_layouts():
    """On two generated layouts past every training and selection seed, the shipped
    predictor calls most frontiers right, far above always answering the commoner class."""
    from mjexplore.learning.pocket_training import collect_episode, load_pocket_config, validate

    config = load_pocket_config(ROOT / "training" / "pockets.yaml")
    config = dataclasses.replace(config, seed=2**30)  # Episode seeds training never used.
    parts = [collect_episode(config, i) for i in range(2)]
    data = {k: np.concatenate([p[k] for p in parts]) for k in ("patches", "lengths", "areas")}
    data["lengths"] = data["lengths"].astype(np.float32)
    predictor = pocket_predictor(SHIPPED)
    small = data["areas"] < predictor.small_area_m2
    figures = validate(predictor.net, data, np.arange(len(small)), small)
    assert figures["validation_samples"] > 100
    assert figures["accuracy"] > figures["majority_accuracy"] + 0.15, figures
    assert figures["large_called_small"] < 0.1, figures


def test_v3_observation_is_v2_with_each_frontier_nodes_pocket(tmp_path):
    from mjexplore.envs import ExplorationEnv
    from mjexplore.envs.observation import POCKET
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.topology.ter import FRONTIER_FLAG

    path = tmp_path / "pockets.safetensors"
    save_pocket_net(path, PocketNet(), 0.5)
    config = load_train_config(ROOT / "training" / "gvn_v3.yaml").env
    v3 = dataclasses.replace(config, observation=dataclasses.replace(
        config.observation, pockets=str(path), pockets_sha256=None))
    v2 = dataclasses.replace(config, observation=dataclasses.replace(
        config.observation, features="v2", pockets=None, pockets_sha256=None))
    obs3, _ = ExplorationEnv(v3).reset(seed=4)
    obs2, _ = ExplorationEnv(v2).reset(seed=4)
    f3 = obs3["node_features"].reshape(256, -1)
    f2 = obs2["node_features"].reshape(256, -1)
    assert np.array_equal(f3[:, :POCKET], f2)
    frontier = f3[:, 5] == FRONTIER_FLAG
    assert frontier.sum() >= 2
    assert ((f3[frontier, POCKET] > 0) & (f3[frontier, POCKET] < 1)).all()
    assert (f3[~frontier, POCKET] == 0).all()


def test_prior_passes_over_nodes_whose_pocket_is_likely_small():
    import torch

    from mjexplore.envs.observation import PATH, POCKET
    from mjexplore.policies.gvn import path_prior

    features = torch.zeros(2, POCKET + 1)
    features[:, PATH] = torch.tensor([2.0, 5.0])
    features[:, POCKET] = torch.tensor([0.9, 0.02])
    assert int(path_prior(features, 1.0).argmax()) == 0  # Nearest-frontier.
    assert int(path_prior(features, 1.0, pocket_m=50.0).argmax()) == 1


def test_v3_needs_a_predictor_and_the_pocket_prior_needs_v3():
    from mjexplore.envs.observation import ObservationConfig
    from mjexplore.learning.train_config import load_train_config

    with pytest.raises(ValueError, match="pockets"):
        ObservationConfig(features="v3")
    with pytest.raises(ValueError, match="v3 only"):
        ObservationConfig(features="v2", pockets="training/pockets.safetensors")
    config = load_train_config(ROOT / "training" / "gvn_v2.yaml")
    with pytest.raises(ValueError, match="prior_pocket_m"):
        dataclasses.replace(config, policy=dataclasses.replace(config.policy,
                                                               prior_pocket_m=50.0))


def _patches_from_padded_layers(grid, frontiers):
    """The patches as the predictor was trained on them: windows of whole-map layers padded
    by a patch on every side (the reference the per-frontier windows must reproduce)."""
    import cv2

    from mjexplore.topology.pockets import PATCH_CELLS, PATCH_RESOLUTION

    out = np.zeros((len(frontiers), 3, PATCH_CELLS, PATCH_CELLS), np.uint8)
    side = max(1, int(round(PATCH_CELLS * PATCH_RESOLUTION / grid.resolution)))
    half = side // 2
    data = grid.data
    layers = np.zeros((2, data.shape[0] + side, data.shape[1] + side), np.float32)
    layers[0, half:half + data.shape[0], half:half + data.shape[1]] = data == 0
    layers[1, half:half + data.shape[0], half:half + data.shape[1]] = data > 0
    own = np.zeros((side, side), np.float32)
    for i, f in enumerate(frontiers):
        r0, c0 = np.round(f.cells.mean(axis=0)).astype(int) - half
        cells = f.cells - (r0, c0)
        inside = ((cells >= 0) & (cells < side)).all(axis=1)
        own[:] = 0.0
        own[cells[inside, 0], cells[inside, 1]] = 1.0
        window = layers[:, r0 + half:r0 + half + side, c0 + half:c0 + half + side]
        for k, layer in enumerate((window[0], window[1], own)):
            resized = layer if side == PATCH_CELLS else cv2.resize(
                layer, (PATCH_CELLS, PATCH_CELLS), interpolation=cv2.INTER_AREA)
            out[i, k] = np.round(np.clip(resized, 0.0, 1.0) * 255.0)
    return out


@pytest.mark.parametrize("resolution", [0.05, 0.1, 0.07])
def test_patches_cut_per_frontier_equal_the_padded_whole_map_ones(resolution):
    rng = np.random.default_rng(int(resolution * 100))
    data = np.full((90, 130), -1, np.int8)
    for _ in range(8):  # Rooms, some against the map's border.
        r, c = rng.integers(0, 80), rng.integers(0, 120)
        data[r:r + rng.integers(4, 30), c:c + rng.integers(4, 40)] = 0
    data[rng.random(data.shape) < 0.03] = 100
    grid = GridMap(data, resolution)
    frontiers = find_frontiers(grid)
    assert len(frontiers) > 5
    assert np.array_equal(frontier_patches(grid, frontiers),
                          _patches_from_padded_layers(grid, frontiers))
