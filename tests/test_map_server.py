import numpy as np
import pytest
import yaml
from conftest import shared_data

from mjexplore.errors import UserInputError
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.scenes.map_server import read_map, write_map


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    data = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.int8), size=(37, 53))
    grid = GridMap(data, 0.05, (-1.25, 3.5, 0.0))
    write_map(tmp_path / "m.yaml", grid)
    back = read_map(tmp_path / "m.yaml")
    assert back.equals(grid)
    # Rows are flipped on disk: the first PGM row is the top (highest y) of the map.
    raw = (tmp_path / "m.pgm").read_bytes()
    pixels = np.frombuffer(raw[-data.size:], np.uint8).reshape(data.shape)
    assert pixels[0, 0] == {UNKNOWN: 205, FREE: 254, OCCUPIED: 0}[int(data[-1, 0])]


def test_reads_explore_bench_maps():
    folder = shared_data("explore_bench")
    grid = read_map(folder / "loop.yaml")
    assert grid.shape == (250, 250) and grid.resolution == pytest.approx(0.1)
    assert grid.origin == (-12.5, -12.5, 0.0)
    free_area = grid.free.sum() * grid.resolution ** 2
    assert free_area == pytest.approx(190, rel=0.1)  # The README's figure for 'loop'.


def test_negate_and_thresholds(tmp_path):
    img = np.array([[0, 100, 255]], np.uint8)
    (tmp_path / "m.pgm").write_bytes(b"P5\n3 1\n255\n" + img.tobytes())
    meta = {"image": "m.pgm", "resolution": 0.1, "origin": [0, 0, 0], "negate": 1,
            "occupied_thresh": 0.65, "free_thresh": 0.196}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(meta))
    assert read_map(tmp_path / "m.yaml").data.tolist() == [[FREE, UNKNOWN, OCCUPIED]]


def _map_with(tmp_path, pixels, **meta):
    import cv2

    cv2.imwrite(str(tmp_path / "m.png"), pixels)
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(
        {"image": "m.png", "resolution": 0.1, "origin": [0, 0, 0], "negate": 0,
         "occupied_thresh": 0.65, "free_thresh": 0.196, **meta}))
    return read_map(tmp_path / "m.yaml").data.tolist()


def test_map_modes_follow_map_server(tmp_path):
    grey = np.array([[0, 60, 150, 205, 254]], np.uint8)  # p = 1, .76, .41, .196, .004
    assert _map_with(tmp_path, grey) == [[OCCUPIED, OCCUPIED, UNKNOWN, UNKNOWN, FREE]]
    assert _map_with(tmp_path, grey, mode="scale") == [[OCCUPIED, OCCUPIED, 47, 0, FREE]]
    raw = np.array([[0, 37, 100, 255]], np.uint8)
    assert _map_with(tmp_path, raw, mode="raw") == [[0, 37, 100, UNKNOWN]]
    assert _map_with(tmp_path, 255 - raw, mode="raw", negate=1) == [[0, 37, 100, UNKNOWN]]
    with pytest.raises(UserInputError, match="raw mode"):
        _map_with(tmp_path, grey, mode="raw")
    with pytest.raises(UserInputError, match="mode 'bananas'"):
        _map_with(tmp_path, grey, mode="bananas")
    # Channels are averaged as real numbers: 205.67 gives p 0.1935 < 0.196, free.
    assert _map_with(tmp_path, np.array([[[205, 206, 206]]], np.uint8)) == [[FREE]]
    # In scale mode a fully transparent pixel in between is unknown; alpha is not averaged.
    rgba = np.array([[[150, 150, 150, 0], [150, 150, 150, 255], [254, 254, 254, 0]]], np.uint8)
    assert _map_with(tmp_path, rgba, mode="scale") == [[UNKNOWN, 47, FREE]]


@pytest.mark.parametrize("case", ["missing_yaml", "not_yaml", "no_image_key", "missing_image",
                                  "corrupt_image", "bad_resolution", "rotated_origin"])
def test_bad_maps_raise_clear_errors(tmp_path, case):
    good = {"image": "m.pgm", "resolution": 0.1, "origin": [0, 0, 0]}
    (tmp_path / "m.pgm").write_bytes(b"P5\n2 2\n255\n" + bytes([254, 0, 254, 205]))
    meta = dict(good)
    path = tmp_path / "m.yaml"
    if case == "missing_yaml":
        path = tmp_path / "nothing.yaml"
    elif case == "not_yaml":
        path.write_text("image: [unclosed\n")
    else:
        if case == "no_image_key":
            del meta["image"]
        elif case == "missing_image":
            meta["image"] = "gone.pgm"
        elif case == "corrupt_image":
            (tmp_path / "m.pgm").write_bytes(b"P5\n200 200\n255\n\x00\x01")
        elif case == "bad_resolution":
            meta["resolution"] = -1
        elif case == "rotated_origin":
            meta["origin"] = [0, 0, 0.5]
        path.write_text(yaml.safe_dump(meta))
    with pytest.raises(UserInputError) as info:
        read_map(path)
    assert len(str(info.value)) > 30
