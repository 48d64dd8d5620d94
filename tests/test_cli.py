import json
import subprocess
import sys

import numpy as np
import pytest

from mjexplore.cli import main
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.scenes.map_server import write_map


def run(*args):
    return subprocess.run([sys.executable, "-m", "mjexplore.cli", *args], capture_output=True,
                          text=True, timeout=120)


def test_help_for_every_command():
    for args in ([], ["scene-gen"], ["drive"]):
        proc = run(*args, "--help")
        assert proc.returncode == 0 and "usage" in proc.stdout


def test_scene_gen_writes_all_outputs(tmp_path):
    proc = run("scene-gen", "maze", "--seed", "3", "--size", "12x10", "--out", str(tmp_path / "s"))
    assert proc.returncode == 0, proc.stderr
    names = sorted(p.name for p in (tmp_path / "s").iterdir())
    assert names == ["map.pgm", "map.yaml", "preview.png", "scene.json", "scene.xml"]
    assert json.loads(proc.stdout)["wall_boxes"] > 4


def wall_map(tmp_path):
    data = np.full((40, 40), OCCUPIED, np.int8)
    data[5:35, 5:35] = FREE
    write_map(tmp_path / "room.yaml", GridMap(data, 0.1, (0.0, 0.0, 0.0)))
    return tmp_path / "room.yaml"


BAD = {
    "unknown family": lambda p: ["scene-gen", "volcano", "--out", str(p / "o")],
    "negative size": lambda p: ["scene-gen", "office", "--size=-3x4", "--out", str(p / "o")],
    "size not WxH": lambda p: ["scene-gen", "office", "--size", "big", "--out", str(p / "o")],
    "negative seed": lambda p: ["scene-gen", "office", "--seed=-1", "--out", str(p / "o")],
    "tiny office": lambda p: ["scene-gen", "office", "--size", "6x6", "--out", str(p / "o")],
    "thin walls": lambda p: ["scene-gen", "rooms", "--wall-thickness", "0.001", "--out",
                             str(p / "o")],
    "no out": lambda p: ["scene-gen", "office"],
    "missing map": lambda p: ["scene-gen", "--from-map", str(p / "none.yaml"), "--out",
                              str(p / "o")],
    "image without resolution": lambda p: ["scene-gen", "--from-map", str(p / "x.png"),
                                           "--out", str(p / "o")],
    "start in wall": lambda p: ["scene-gen", "--from-map", str(wall_map(p)), "--start", "0.2,0.2",
                                "--out", str(p / "o")],
    "start outside": lambda p: ["scene-gen", "--from-map", str(wall_map(p)), "--start", "90,9",
                                "--out", str(p / "o")],
    "bad start": lambda p: ["scene-gen", "--from-map", str(wall_map(p)), "--start", "a,b",
                            "--out", str(p / "o")],
    "unknown scene": lambda p: ["drive", "--scene", "atlantis", "--out", str(p / "o")],
    "unknown profile": lambda p: ["drive", "--profile", "turbo", "--out", str(p / "o")],
    "negative duration": lambda p: ["drive", "--duration=-4", "--out", str(p / "o")],
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_exits_2_without_partial_files(tmp_path, case, capsys):
    (tmp_path / "x.png").write_bytes(b"\x89PNG not really")
    with pytest.raises(SystemExit) as info:
        sys.exit(main(BAD[case](tmp_path)))
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "error" in err and len(err) > 40
    assert not (tmp_path / "o").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".o.")]


def test_corrupt_map_image(tmp_path, capsys):
    yaml_path = wall_map(tmp_path)
    (tmp_path / "room.pgm").write_bytes(b"P5\n40 40\n255\n\x01\x02")  # Truncated.
    assert main(["scene-gen", "--from-map", str(yaml_path), "--out", str(tmp_path / "o")]) == 2
    assert "could not be decoded" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_drive_writes_run_folder(tmp_path):
    assert main(["drive", "--scene", "lobby", "--duration", "5", "--out", str(tmp_path / "r")]) == 0
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["simulated_time_s"] == pytest.approx(5.0)
    assert summary["mujoco_warnings"] == {}
    lines = (tmp_path / "r" / "kinematics.csv").read_text().splitlines()
    assert lines[0].startswith("t,linear_velocity") and len(lines) == 1 + 5 * 20 + 1
    assert (tmp_path / "r" / "trajectory.png").stat().st_size > 1000
