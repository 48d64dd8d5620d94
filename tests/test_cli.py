import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mjexplore.cli import main
from mjexplore.io.provenance import file_sha256
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.policies.models import MODELS_DIR
from mjexplore.scenes.map_server import write_map


def run(*args):
    return subprocess.run([sys.executable, "-m", "mjexplore.cli", *args], capture_output=True,
                          text=True, timeout=120)


def test_help_for_every_command():
    for args in ([], ["scene-gen"], ["drive"]):
        proc = run(*args, "--help")
        assert proc.returncode == 0 and "usage" in proc.stdout


def test_collect_help_names_every_experiment_the_report_knows():
    from mjexplore.eval.experiments import EXPERIMENTS

    text = " ".join(run("collect", "--help").stdout.split())
    known = text.split("Experiments the report knows: ")[1].split(".")[0]
    assert sorted(known.split(", ")) == sorted(exp.name for exp in EXPERIMENTS)


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
    "unknown explorer": lambda p: ["explore", "--explorer", "teleport", "--out", str(p / "o")],
    "bad target ratio": lambda p: ["explore", "--target-ratio", "1.5", "--out", str(p / "o")],
    "negative max time": lambda p: ["explore", "--max-time=-1", "--out", str(p / "o")],
    "bench unknown scene": lambda p: ["bench", "--scenes", "atlantis", "--out", str(p / "o")],
    "bench no workers": lambda p: ["bench", "--workers", "0", "--out", str(p / "o")],
    "bench a billion seeds": lambda p: ["bench", "--seeds", "1000000000", "--out", str(p / "o")],
    "bench team placement twice": lambda p: ["bench", "--robots", "2", "--starts", "drawn,drawn",
                                             "--out", str(p / "o")],
    "bench unknown explorer": lambda p: ["bench", "--explorers", "nearest,magic", "--out",
                                         str(p / "o")],
    # Scene files.
    "malformed MJCF": lambda p: ["explore", "--scene", str(_write(p / "bad.xml", "<mujoco><wor"))
                                 , "--out", str(p / "o")],
    "map missing image": lambda p: ["scene-gen", "--from-map", str(_write(
        p / "m.yaml", "image: gone.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n")), "--out", str(p / "o")],
    "map no free space": lambda p: ["scene-gen", "--from-map", str(solid_map(p)), "--out",
                                    str(p / "o")],
    "map yaml not a mapping": lambda p: ["scene-gen", "--from-map", str(_write(
        p / "l.yaml", "- just\n- a list\n")), "--out", str(p / "o")],
    # Training configs and checkpoints.
    "train missing config": lambda p: ["train", "--config", str(p / "none.yaml"), "--out",
                                       str(p / "o")],
    "train unknown key": lambda p: ["train", "--config",
                                    str(_write(p / "c.yaml", "ppo:\n  lr: 1\n")),
                                    "--out", str(p / "o")],
    "train wrong type": lambda p: ["train", "--config", str(_write(
        p / "c.yaml", "total_steps: many\n")), "--out", str(p / "o")],
    "train out of range": lambda p: ["train", "--config", str(_write(
        p / "c.yaml", "ppo: {gamma: 1.5}\n")), "--out", str(p / "o")],
    "train bad masking": lambda p: ["train", "--config", str(_write(
        p / "c.yaml", "policy: {masking: maybe}\n")), "--out", str(p / "o")],
    "train bad env": lambda p: ["train", "--config", str(_write(
        p / "c.yaml", "env: {scenes: [], valid_actions: all_nodes}\n")), "--out", str(p / "o")],
    "train bad episode rate": lambda p: ["train", "--config", str(_write(
        p / "c.yaml", "env: {episode: {control_rate_hz: -10.0}}\n")), "--out", str(p / "o")],
    "train bad replan rate": lambda p: ["train", "--config", str(_write(
        p / "c.yaml", "env: {episode: {navigator: {replan_rate_hz: 0.0}}}\n")), "--out",
        str(p / "o")],
    "train yaml syntax": lambda p: ["train", "--config", str(_write(p / "c.yaml", "ppo: [1,\n")),
                                    "--out", str(p / "o")],
    "train resume nothing": lambda p: ["train", "--config", str(_write(p / "c.yaml", "seed: 1\n")),
                                       "--out", str(p / "o"), "--resume"],
    "truncated checkpoint": lambda p: ["train", "--config", str(_write(p / "c.yaml", "seed: 1\n")),
                                       "--out", str(broken_run(p)), "--resume"],
    "policy not weights": lambda p: ["explore", "--explorer", "gvn", "--policy",
                                     str(_write(p / "w.safetensors", "not weights")), "--out",
                                     str(p / "o")],
    "policy for classic explorer": lambda p: ["explore", "--explorer", "nearest", "--policy",
                                              str(_write(p / "w.safetensors", "x")), "--out",
                                              str(p / "o")],
    "from-map with size": lambda p: ["scene-gen", "--from-map", str(wall_map(p)), "--size",
                                     "10x10", "--out", str(p / "o")],
    "from-map yaml with resolution": lambda p: ["scene-gen", "--from-map", str(wall_map(p)),
                                                "--resolution", "0.05", "--out", str(p / "o")],
    "damaged scene.json": lambda p: ["explore", "--scene", str(_scene_with_json(p, "{bad")),
                                     "--out", str(p / "o")],
    "scene.json not an object": lambda p: ["explore", "--scene",
                                           str(_scene_with_json(p, "[1, 2]")), "--out",
                                           str(p / "o")],
    # Rendering.
    "render not a run": lambda p: ["render", str(p), "--out", str(p / "o")],
    "video odd size": lambda p: ["explore", "--video", str(p / "v.mp4"), "--video-size",
                                 "641x480", "--out", str(p / "o")],
    "video zero fps": lambda p: ["explore", "--video", str(p / "v.mp4"), "--video-fps", "0",
                                 "--out", str(p / "o")],
    # Results report.
    "collect not a sweep": lambda p: ["collect", str(p), "--experiment", "table1", "--data",
                                      str(p / "o")],
    "collect bad experiment name": lambda p: ["collect", str(p), "--experiment", "../t1",
                                              "--data", str(p / "o")],
    "collect unknown experiment": lambda p: ["collect", str(p), "--experiment", "tabel1",
                                             "--data", str(p / "o")],
    "explore a model as explorer": lambda p: ["explore", "--explorer", "gvn_paper", "--out",
                                              str(p / "o")],
    "explore a team method alone": lambda p: ["explore", "--explorer", "assign_greedy",
                                              "--out", str(p / "o")],
    "report no data": lambda p: ["report", "--data", str(p / "none"), "--out",
                                 str(p / "o" / "r.md")],
    "report damaged summary": lambda p: ["report", "--data",
                                         str(_write(p / "table1.json", "{").parent),
                                         "--out", str(p / "o" / "r.md")],
    "report unknown summary": lambda p: ["report", "--data",
                                         str(_write(p / "table_1.json", "{}").parent),
                                         "--out", str(p / "o" / "r.md")],
}


def _write(path, text):
    path.write_text(text)
    return path


def _scene_with_json(tmp_path, text):
    import shutil

    from mjexplore.scenes.canonical import resolve_scene

    folder = tmp_path / "scene"
    shutil.copytree(resolve_scene("train_loop").xml.parent, folder)
    (folder / "scene.json").write_text(text)
    return folder


def solid_map(tmp_path):
    write_map(tmp_path / "solid.yaml", GridMap(np.full((30, 30), OCCUPIED, np.int8), 0.1,
                                               (0.0, 0.0, 0.0)))
    return tmp_path / "solid.yaml"


def broken_run(tmp_path):
    ckpt = tmp_path / "run" / "checkpoints"
    ckpt.mkdir(parents=True)
    (ckpt / "step_000000064.pt").write_bytes(b"PK\x03\x04truncated")
    (ckpt / "latest.json").write_text('{"checkpoint": "step_000000064.pt"}')
    return tmp_path / "run"


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


def test_bad_input_table_is_large_enough():
    assert len(BAD) + 1 >= 25  # The floor (+1: the corrupt map image below).


def test_corrupt_map_image(tmp_path, capsys):
    yaml_path = wall_map(tmp_path)
    (tmp_path / "room.pgm").write_bytes(b"P5\n40 40\n255\n\x01\x02")  # Truncated.
    assert main(["scene-gen", "--from-map", str(yaml_path), "--out", str(tmp_path / "o")]) == 2
    assert "could not be decoded" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", [
    ["scene-gen", "maze", "--size", "6x6"],
    ["explore", "--scene", "train_loop", "--max-time", "2", "--no-mcap"],
    ["drive", "--scene", "lobby", "--duration", "1"]])
def test_an_output_folder_of_other_files_is_refused_and_kept(tmp_path, command, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("precious")
    assert main([*command, "--out", str(mine)]) == 2
    assert "choose a new folder" in capsys.readouterr().err
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["mine"]
    assert main([*command, "--out", "/"]) == 2


def test_an_earlier_output_is_replaced_with_the_usual_permissions(tmp_path):
    out = tmp_path / "scene"
    old = os.umask(0o022)
    try:
        for seed in ("1", "2"):
            assert main(["scene-gen", "maze", "--size", "6x6", "--seed", seed,
                         "--out", str(out)]) == 0
    finally:
        os.umask(old)
    assert json.loads((out / "scene.json").read_text())["seed"] == 2
    assert oct(out.stat().st_mode & 0o777) == oct(0o755)
    assert oct((out / "scene.xml").stat().st_mode & 0o777) == oct(0o644)


def test_from_map_takes_the_name_given(tmp_path):
    assert main(["scene-gen", "--from-map", str(wall_map(tmp_path)), "--name", "my_room",
                 "--out", str(tmp_path / "o")]) == 0
    assert json.loads((tmp_path / "o" / "scene.json").read_text())["name"] == "my_room"
    assert 'model="my_room"' in (tmp_path / "o" / "scene.xml").read_text()


def test_cnn_explorer_takes_a_policy_file(tmp_path):
    weights = tmp_path / "mine.safetensors"
    weights.write_bytes((MODELS_DIR / "cnn_v2" / "policy.safetensors").read_bytes())
    assert main(["explore", "--scene", "train_loop", "--explorer", "cnn", "--policy",
                 str(weights), "--max-time", "3", "--no-mcap",
                 "--out", str(tmp_path / "o")]) == 0
    config = json.loads((tmp_path / "o" / "config.json").read_text())
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    sha = file_sha256(weights)
    assert config["explorer"] == metrics["explorer"] == f"cnn_mine_{sha[:8]}"
    assert metrics["policy"] == str(weights) and config["spec"] == f"cnn:{weights}"
    assert config["policy"] == {"name": str(weights), "file": str(weights), "sha256": sha,
                                "recipe": metrics["policy_recipe"]}


def test_the_run_records_name_the_policy_that_ran(tmp_path):
    assert main(["explore", "--scene", "train_loop", "--explorer", "gvn", "--policy",
                 "gvn_paper", "--max-time", "3", "--no-mcap", "--out", str(tmp_path / "o")]) == 0
    config = json.loads((tmp_path / "o" / "config.json").read_text())
    assert config["explorer"] == "gvn"  # The paper's recipe keeps its label in the tables.
    assert config["spec"] == "gvn:gvn_paper"
    assert config["policy"]["name"] == "gvn_paper"
    assert config["policy"]["file"] == "models/gvn_paper/policy.safetensors"
    assert config["policy"]["sha256"] == file_sha256(MODELS_DIR / "gvn_paper" /
                                                     "policy.safetensors")


@pytest.mark.slow
def test_a_sweep_of_policies_given_by_path_is_collected_completely(tmp_path):
    run = tmp_path / "train" / "mine"  # Like a run folder of 'mjexplore train'.
    run.mkdir(parents=True)
    (run / "policy.safetensors").write_bytes(
        (MODELS_DIR / "gvn_v3" / "policy.safetensors").read_bytes())
    out = tmp_path / "bench"
    assert main(["bench", "--scenes", "train_loop", "--explorers", f"nearest,gvn:{run}",
                 "--seeds", "2", "--workers", "1", "--max-time", "5", "--no-progress",
                 "--out", str(out)]) == 0
    label = f"gvn_mine_{file_sha256(run / 'policy.safetensors')[:8]}"
    assert sorted(p.name for p in (out / "runs" / "train_loop").iterdir()) == [label, "nearest"]
    assert main(["collect", str(out), "--experiment", "table1", "--data",
                 str(tmp_path / "data")]) == 0
    summary = json.loads((tmp_path / "data" / "table1.json").read_text())
    assert sorted((r["method"], r["seed"]) for r in summary["runs"]) == \
        [(label, 0), (label, 1), ("nearest", 0), ("nearest", 1)]
    assert summary["policies"][label]["sha256"] == file_sha256(run / "policy.safetensors")


def test_an_unknown_gl_backend_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MUJOCO_GL", "bogus")
    assert main(["explore", "--scene", "train_loop", "--out", str(tmp_path / "o")]) == 2
    assert "MUJOCO_GL='bogus'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_drive_writes_run_folder(tmp_path):
    assert main(["drive", "--scene", "lobby", "--duration", "5", "--out", str(tmp_path / "r")]) == 0
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["simulated_time_s"] == pytest.approx(5.0)
    assert summary["mujoco_warnings"] == {}
    lines = (tmp_path / "r" / "kinematics.csv").read_text().splitlines()
    assert lines[0].startswith("t,linear_velocity") and len(lines) == 1 + 5 * 20 + 1
    assert (tmp_path / "r" / "trajectory.png").stat().st_size > 1000


def test_explore_writes_run_folder(tmp_path):
    out = tmp_path / "run"
    assert main(["explore", "--scene", "train_loop", "--explorer", "potential", "--max-time", "20",
                 "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("iou", "exploration_ratio", "exploration_time_s", "path_length_m", "t80_s",
                "t985_s", "collisions", "end_reason"):
        assert key in metrics
    assert metrics["end_reason"] in ("explored", "time_limit")
    config = json.loads((out / "config.json").read_text())
    assert config["explorer"] == "potential" and config["git_revision"]
    for name in ("ratio.csv", "kinematics.csv", "ratio.png", "kinematics.png", "map.png",
                 "episode.mcap"):
        assert (out / name).stat().st_size > 100


def test_bench_writes_tables_and_resumes(tmp_path):
    out = tmp_path / "bench"
    args = ["bench", "--scenes", "train_loop", "--explorers", "nearest,potential", "--seeds", "1",
            "--workers", "1", "--max-time", "15", "--out", str(out)]
    assert main(args) == 0
    table = (out / "results.md").read_text()
    assert "| train_loop | nearest | 1 |" in table and "| train_loop | potential | 1 |" in table
    assert (out / "results.csv").read_text().startswith("scene,method,runs,explored,IoU")
    assert (out / "ratio_train_loop.png").is_file()
    assert (out / "kinematics_train_loop.png").is_file()
    done = out / "runs" / "train_loop" / "nearest" / "seed0" / "metrics.json"
    stamp = done.stat().st_mtime_ns
    assert main(args) == 0  # Finished episodes are skipped, not run again.
    assert done.stat().st_mtime_ns == stamp


@pytest.mark.parametrize(("argv", "says"), [
    (["collect", "{p}", "--experiment", "tabel1", "--data", "{p}/o"],
     ["mjexplore collect: error:", "did you mean 'table1'"]),
    (["collect", "{p}/none", "--experiment", "table1", "--command", "x", "--data", "{p}/o"],
     ["mjexplore collect: error:"]),
    (["explore", "--explorer", "gvn_paper", "--out", "{p}/o"],
     ["--explorer gvn --policy gvn_paper", "gvn:gvn_paper"]),
    (["explore", "--explorer", "assign_greedy", "--out", "{p}/o"], ["add --robots 2"]),
])
def test_errors_name_the_command_and_the_fix(tmp_path, capsys, argv, says):
    assert main([a.format(p=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "None" not in err, err
    for text in says:
        assert text in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv", [["explore", "--seed", "x"], ["bench", "--nope"],
                                  ["explore", "--explorer"], ["no-such-command"], []])
def test_argument_errors_are_one_line_that_points_at_help(capsys, argv):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage:" not in err and "--help)" in err, err


def test_an_empty_config_is_refused_not_trained_on_defaults(tmp_path, capsys):
    (tmp_path / "empty.yaml").write_text("# nothing but a comment\n")
    assert main(["train", "--config", str(tmp_path / "empty.yaml"), "--out",
                 str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "is empty" in err and err.count("\n") == 1
    assert not (tmp_path / "run").exists()


def test_a_misspelt_family_is_named_before_anything_is_written(tmp_path, capsys):
    config = tmp_path / "typo.yaml"
    config.write_text("extends: " + str(Path(__file__).resolve().parents[1] / "training"
                                        / "gvn_v3.yaml") + "\n"
                      "env:\n  procedural: {families: [offfice]}\n")
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "offfice" in err and "widen" not in err and err.count("\n") == 1, err
    assert not (tmp_path / "run").exists()


def test_an_all_wall_map_and_a_text_file_as_weights_are_one_line(tmp_path, capsys):
    import shutil

    import cv2

    from mjexplore.scenes.canonical import resolve_scene

    scene = tmp_path / "black"
    shutil.copytree(resolve_scene("train_loop").xml.parent, scene)
    image = cv2.imread(str(scene / "map.pgm"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(scene / "map.pgm"), np.zeros_like(image))
    (tmp_path / "w.safetensors").write_text("not weights")
    corrupt = tmp_path / "corrupt"
    shutil.copytree(resolve_scene("train_loop").xml.parent, corrupt)
    (corrupt / "scene.xml").write_text("<mujoco><worldbody><bad")
    for argv, says in (
            (["bench", "--scenes", f"train_loop,{corrupt}", "--explorers", "nearest",
              "--seeds", "1", "--out", str(tmp_path / "o")], "failed to compile"),
            (["explore", "--scene", str(scene), "--out", str(tmp_path / "o")], "no free cell"),
            (["bench", "--scenes", str(scene), "--explorers", "nearest", "--seeds", "1",
              "--out", str(tmp_path / "o")], "no free cell"),
            (["bench", "--scenes", "train_loop", "--explorers",
              f"gvn:{tmp_path / 'w.safetensors'}", "--seeds", "1", "--out",
              str(tmp_path / "o")], "not a readable safetensors file")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1 and "Traceback" not in err, err
        assert not (tmp_path / "o").exists()


def test_a_sweep_started_again_with_fewer_methods_keeps_both_commands(tmp_path):
    out = tmp_path / "bench"
    first = ["bench", "--scenes", "train_loop", "--explorers", "nearest,potential", "--seeds",
             "1", "--workers", "1", "--max-time", "5", "--no-progress", "--out", str(out)]
    again = first[:4] + ["nearest"] + first[5:]
    assert main(first) == 0 and main(again) == 0
    sweep = json.loads((out / "sweep.json").read_text())
    assert [plan["explorers"] for plan in sweep["history"]] == [["nearest", "potential"],
                                                                ["nearest"]]
    assert sweep["explorers"] == ["nearest"]  # The last start's plan.
    assert main(["collect", str(out), "--experiment", "table1", "--data",
                 str(tmp_path / "data")]) == 0
    summary = json.loads((tmp_path / "data" / "table1.json").read_text())
    # potential's runs were made by the first command: the summary names it, and so does
    # each run.
    assert "nearest,potential" in summary["command"]
    made = json.loads((out / "runs" / "train_loop" / "potential" / "seed0" /
                       "config.json").read_text())["command"]
    assert made == " ".join(["mjexplore"] + first)
    assert {r["method"] for r in summary["runs"]} == {"nearest", "potential"}


@pytest.mark.parametrize("team, experiment, says", [
    (True, "table1", "collect it as one of teams, teams_explore_bench"),
    (False, "teams", "is a single-robot sweep"),
])
def test_collect_refuses_a_sweep_of_the_other_kind(tmp_path, capsys, team, experiment, says):
    run = tmp_path / "sweep" / "runs" / "office" / (Path("drawn") if team else Path()) / \
        "nearest" / "seed0"
    run.mkdir(parents=True)
    (run / "metrics.json").write_text('{"end_reason": "explored"}')
    assert main(["collect", str(tmp_path / "sweep"), "--experiment", experiment, "--data",
                 str(tmp_path / "data")]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1, err
    assert not (tmp_path / "data").exists()


def test_collect_training_refuses_a_damaged_eval_csv_and_the_report_keeps_its_outputs(
        tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "eval.csv").write_text("steps,scene\nten,office\n")
    assert main(["collect-training", str(run), "--data", str(tmp_path / "data")]) == 2
    err = capsys.readouterr().err
    assert "not an eval.csv" in err and err.count("\n") == 1, err
    assert not (tmp_path / "data").exists()
    # A damaged record already in a data folder: the report fails and writes nothing.
    (tmp_path / "data" / "training" / "run").mkdir(parents=True)
    (tmp_path / "data" / "training" / "run" / "eval.csv").write_text("steps\n1\n")
    out = tmp_path / "report" / "results.md"
    assert main(["report", "--data", str(tmp_path / "data"), "--out", str(out)]) == 2
    assert "not an eval.csv" in capsys.readouterr().err
    assert not (tmp_path / "report").exists()


@pytest.mark.parametrize("argv", [
    ["bench", "--scenes", "train_loop", "--explorers", "nearest", "--seeds", "1"],
    ["bench", "--scenes", "train_loop", "--seeds", "1", "--robots", "2"],
    ["train-pockets", "--config", "training/pockets.yaml"],
    ["imitate", "--config", "training/gvn_dagger.yaml"],
    ["train-predictor", "--config", "training/predictor.yaml"],
])
def test_commands_refuse_an_out_folder_of_other_files(tmp_path, capsys, argv):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    repo = Path(__file__).resolve().parents[1]
    argv = [str(repo / a) if a.startswith("training/") else a for a in argv]
    assert main(argv + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "notes.txt" in err and err.count("\n") == 1, err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_collect_lists_every_episode_it_leaves_out_and_can_be_strict(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "--scenes", "train_loop", "--explorers", "nearest", "--seeds", "2",
                 "--workers", "1", "--max-time", "3", "--no-progress", "--out", str(out)]) == 0
    runs = out / "runs" / "train_loop" / "nearest"
    cut = json.loads((runs / "seed1" / "metrics.json").read_text()) | {
        "end_reason": "interrupted"}
    (runs / "seed1" / "metrics.json").write_text(json.dumps(cut))
    (runs / "seed2.failed.json").write_text(json.dumps({"error": "ValueError: boom"}))
    stray = out / "runs" / "train_loop" / "nearest" / "seed0" / "extra" / "seed9"
    stray.mkdir(parents=True)
    (stray / "metrics.json").write_text('{"end_reason": "explored"}')
    capsys.readouterr()
    argv = ["collect", str(out), "--experiment", "table1", "--data", str(tmp_path / "d")]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["skipped"] == 3 and json.loads(captured.out)["runs"] == 1
    for text in ("runs/train_loop/nearest/seed1: interrupted",
                 "runs/train_loop/nearest/seed2: failed: ValueError: boom",
                 "runs/train_loop/nearest/seed0/extra/seed9: not a run folder"):
        assert text in captured.err, captured.err
    assert main(argv + ["--strict"]) == 1
