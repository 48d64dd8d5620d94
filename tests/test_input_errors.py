"""Bad input through the command line: one stderr line that names the fix, exit code 2 and
nothing written under --out (an image as the scene, a --live-host that is no address of
this machine, bench's --starts hints, --robots beyond the room around the start, and
Explore-Bench's placements on scenes that only share a name with its maps)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_data

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.eval.placements import team_starts
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.team import check_starts, draw_starts, parse_starts


def refused(capsys, out, argv) -> str:
    """Runs ``argv`` and returns its one error line; checks exit 2 and that ``out`` was not
    made."""
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    assert not out.exists()
    return lines[0]


def test_an_image_as_the_scene_says_how_to_import_it(tmp_path, capsys):
    image = tmp_path / "black.pgm"
    image.write_bytes(b"P5\n4 4\n255\n" + bytes(16))
    out = tmp_path / "run"
    err = refused(capsys, out, ["explore", "--scene", str(image), "--out", str(out)])
    assert "is an image, not a scene" in err and "fix the XML" not in err
    assert "scene-gen --from-map" in err and "--resolution" in err
    assert "map_server YAML" in err  # What a scene is.


def test_an_image_beside_its_yaml_points_at_the_yaml(tmp_path, capsys):
    image = tmp_path / "map.pgm"
    image.write_bytes(b"P5\n4 4\n255\n" + bytes(16))
    (tmp_path / "map.yaml").write_text("image: map.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    out = tmp_path / "b"
    err = refused(capsys, out, ["bench", "--scenes", str(image), "--out", str(out)])
    assert "map.yaml" in err and "is an image" in err


def test_a_text_file_or_a_mesh_as_the_scene(tmp_path, capsys):
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    out = tmp_path / "run"
    err = refused(capsys, out, ["explore", "--scene", str(text), "--out", str(out)])
    assert "is not a scene" in err and "fix the XML" not in err
    mesh = tmp_path / "house.glb"
    mesh.write_bytes(b"glTF")
    err = refused(capsys, out, ["explore", "--scene", str(mesh), "--out", str(out)])
    assert "3D model" in err and "--from-mesh" in err


@pytest.mark.parametrize("host, says", [("256.1.1.1", "not a valid IP address"),
                                        ("8.8.8.8", "not an address of this machine"),
                                        ("no-such-host.invalid", "not a valid address")])
def test_a_live_host_that_cannot_be_bound_is_named(tmp_path, capsys, host, says):
    out = tmp_path / "run"
    err = refused(capsys, out, ["explore", "--scene", "train_loop", "--live", "0",
                                "--live-host", host, "--max-time", "1", "--out", str(out)])
    assert says in err and "free port" not in err and "127.0.0.1" in err


@pytest.mark.parametrize("starts", ["near", "1,2,0;3,4,0", "close,nearby"])
def test_bench_starts_hints_name_only_what_bench_takes(tmp_path, capsys, starts):
    out = tmp_path / "b"
    err = refused(capsys, out, ["bench", "--scenes", "train_loop", "--robots", "2",
                                "--starts", starts, "--out", str(out)])
    assert "close" in err and "far" in err and "drawn" in err
    hints = err.replace(repr(starts), "")
    assert "X,Y" not in hints and ";" not in hints


def test_bench_placements_on_a_canonical_scene_are_refused_up_front(tmp_path, capsys):
    """It used to log a traceback, exit 0 and miss the team's row."""
    out = tmp_path / "b"
    err = refused(capsys, out, ["bench", "--robots", "2", "--starts", "far", "--scenes",
                                "loop_with_corridor", "--out", str(out)])
    assert "not one of its maps" in err and "--starts drawn" in err and "X,Y" not in err


@pytest.mark.parametrize("scene", ["office", "loop_with_corridor"])
def test_explore_placements_apply_to_explore_bench_maps_only(tmp_path, capsys, scene):
    out = tmp_path / "run"
    err = refused(capsys, out, ["explore", "--robots", "2", "--starts", "far", "--scene",
                                scene, "--out", str(out)])
    assert "not one of its maps" in err and "drawn" in err and "X,Y,YAW" in err


def test_explore_bench_maps_keep_their_placements():
    room = resolve_scene(shared_data("explore_bench", "loop_with_corridor.yaml"))
    assert room.metadata["explore_bench"] == "loop_with_corridor"
    assert team_starts(room, "far", 2) == [(8.0, 8.0, 1.57), (-8.0, -8.0, 1.57)]
    assert team_starts(room, "drawn", 2) is None
    assert "explore_bench" not in resolve_scene("loop_with_corridor").metadata


def test_explore_refuses_an_unknown_placement_with_every_form(tmp_path, capsys):
    out = tmp_path / "run"
    err = refused(capsys, out, ["explore", "--robots", "2", "--starts", "near", "--scene",
                                "train_loop", "--out", str(out)])
    assert "close" in err and "drawn" in err and "1,2,0;3,2,1.57" in err


@pytest.mark.parametrize("command", ["explore", "bench"])
def test_more_robots_than_fit_around_the_start_are_refused(tmp_path, capsys, command):
    out = tmp_path / "r"
    scene = ["--scene" if command == "explore" else "--scenes", "loop_with_corridor"]
    err = refused(capsys, out, [command, *scene, "--robots", "50", "--max-time", "5",
                                "--out", str(out)])
    assert "50 robots do not fit" in err and "1-3 m" in err
    most = int(err.split("use --robots ")[1].split()[0])
    assert 2 <= most < 50 and f"at most {most} robots" in err


def test_drawn_starts_stay_in_the_ring_up_to_the_most_that_fit():
    scene = resolve_scene("loop_with_corridor")
    grid, first = scene.ground_truth, scene.start
    with pytest.raises(UserInputError, match="at most") as info:
        draw_starts(grid, first, 50, np.random.default_rng(0))
    most = int(str(info.value).split("use --robots ")[1].split()[0])
    for n in (2, most // 2 + 1, most):
        for seed in range(3):
            starts = draw_starts(grid, first, n, np.random.default_rng([seed, n]))
            assert len(starts) == n and starts[0] == tuple(first)
            check_starts(grid, starts, min_separation=1.0)
            d = np.hypot(*(np.array([p[:2] for p in starts[1:]]) - first[:2]).T)
            assert ((d >= 1.0 - 1e-6) & (d <= 3.0 + 1e-6)).all()
    with pytest.raises(UserInputError, match=f"use --robots {most} or fewer"):
        draw_starts(grid, first, most + 1, np.random.default_rng(1))


def test_parse_starts_still_reads_poses():
    assert parse_starts("1,2;3,4,1") == [(1.0, 2.0, 0.0), (3.0, 4.0, 1.0)]
