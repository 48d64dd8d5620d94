"""A newcomer's first hour: every CLI failure is one line and exit 2 with nothing left
behind, weights are checked, and long work shows it is alive without drawing into pipes."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_learning import TINY

from mjexplore.cli import build_parser, main
from mjexplore.errors import UserInputError
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.policies.models import MODELS_DIR
from mjexplore.scenes.map_server import write_map

REPO = Path(__file__).resolve().parents[1]

def tiny_config(folder: Path, total: int = 16, n_envs: int = 1, observation: str = "") -> Path:
    path = folder / "tiny.yaml"
    path.write_text(TINY.format(total=total, n_envs=n_envs).replace(
        "memory_length: 3}", f"memory_length: 3{observation}}}"))
    return path


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def refused(args: list[str], tmp_path: Path, capsys, inputs: list[Path] = ()) -> str:
    """Runs the CLI with ``args``: it must exit 2 with one line on stderr, no traceback,
    and leave ``tmp_path`` as it was (``inputs`` made before are part of it)."""
    capsys.readouterr()
    before = listing(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and "error: " in err
    assert listing(tmp_path) == before
    return err


# ------------------------------------------------------------------ unusable output paths

def _room(tmp_path: Path) -> Path:
    data = np.full((40, 40), OCCUPIED, np.int8)
    data[5:35, 5:35] = FREE
    write_map(tmp_path / "inputs" / "room.yaml", GridMap(data, 0.1, (0.0, 0.0, 0.0)))
    return tmp_path / "inputs" / "room.yaml"


# Each subcommand with an output in a place given as OUT (a path below a file, or a
# folder of a virtual filesystem), and how it names the output.
OUTPUTS = {
    "scene-gen": lambda p, out: ["scene-gen", "maze", "--size", "6x6", "--out", out],
    "drive": lambda p, out: ["drive", "--scene", "lobby", "--duration", "1", "--out", out],
    "explore": lambda p, out: ["explore", "--scene", "train_loop", "--max-time", "2",
                               "--out", out],
    "bench": lambda p, out: ["bench", "--scenes", "train_loop", "--explorers", "nearest",
                             "--seeds", "1", "--out", out],
    "train": lambda p, out: ["train", "--config", str(tiny_config(p / "inputs")), "--out",
                             out],
    "train-pockets": lambda p, out: ["train-pockets", "--config",
                                     str(REPO / "training" / "pockets.yaml"), "--out", out],
    "collect": lambda p, out: ["collect", str(p / "inputs"), "--experiment", "table1",
                               "--data", out],
    "report": lambda p, out: ["report", "--data", str(REPO / "docs" / "results" / "data"),
                              "--out", out + ".md"],
    "render": lambda p, out: ["render", str(p / "inputs"), "--out", out + ".mp4"],
}


@pytest.mark.parametrize("command", list(OUTPUTS))
@pytest.mark.parametrize("place", ["below a file", "virtual filesystem"])
def test_an_unusable_output_path_is_one_line(tmp_path, capsys, command, place):
    (tmp_path / "inputs").mkdir()
    (tmp_path / "inputs" / "a_file").write_text("in the way")
    out = (str(tmp_path / "inputs" / "a_file" / "x") if place == "below a file"
           else "/proc/mjexplore_x")
    err = refused(OUTPUTS[command](tmp_path, out), tmp_path, capsys)
    assert ("a_file" in err and "is a file" in err) if place == "below a file" else \
        "/proc" in err and "choose a folder you can write to" in err


def test_an_unwritable_folder_is_one_line(tmp_path, capsys, monkeypatch):
    """No permission (root ignores modes, so the refusal is simulated where it is made)."""
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkdtemp", refuse)
    err = refused(["scene-gen", "maze", "--size", "6x6", "--out", str(tmp_path / "s")],
                  tmp_path, capsys)
    assert "permission denied" in err


def test_an_os_error_is_one_line_naming_the_path(tmp_path, capsys, monkeypatch):
    """An OSError that no check foresaw still ends as one line with the path and a fix."""
    import mjexplore.scenes.scene as scene

    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device", str(tmp_path / "s" / "scene.xml"))

    monkeypatch.setattr(scene, "write_text_atomic", fail)
    err = refused(["scene-gen", "maze", "--size", "6x6", "--out", str(tmp_path / "s")],
                  tmp_path, capsys)
    assert "No space left on device" in err and "scene.xml" in err and "choose another" in err


def test_export_into_a_missing_folder_is_refused(tmp_path, capsys):
    err = refused(["scene-gen", "maze", "--size", "6x6", "--out", str(tmp_path / "s"),
                   "--export", str(tmp_path / "nonexistent" / "dir" / "x.glb")], tmp_path,
                  capsys)
    assert "does not exist" in err
    refused(["scene-gen", "--from-scene", "maze", "--export",
             str(tmp_path / "nonexistent" / "x.glb")], tmp_path, capsys)


# ------------------------------------------------------------------ missing or damaged inputs

def test_a_workers_missing_input_is_its_one_line(tmp_path, capsys):
    """The pocket predictor is read in the env workers: their message, not their
    tracebacks and the parent's broken pipe."""
    (tmp_path / "inputs").mkdir()
    config = tiny_config(tmp_path / "inputs", n_envs=2, observation=(
        ", features: v3, pockets: " + str(tmp_path / "gone.safetensors")))
    err = refused(["train", "--config", str(config), "--out", str(tmp_path / "run")],
                  tmp_path, capsys)
    assert "cannot read the pocket predictor" in err and "gone.safetensors" in err


def test_a_map_yaml_with_an_empty_threshold_names_it(tmp_path, capsys):
    yaml_path = _room(tmp_path)
    text = yaml_path.read_text().replace("occupied_thresh: 0.65", "occupied_thresh:")
    yaml_path.write_text(text)
    err = refused(["scene-gen", "--from-map", str(yaml_path), "--out", str(tmp_path / "o")],
                  tmp_path, capsys)
    assert "occupied_thresh is empty" in err and "0.65" in err and "NoneType" not in err


def test_the_onnx_actor_names_missing_observation_keys(tmp_path):
    import onnx
    from onnx import TensorProto, helper

    from mjexplore.policies.onnx_export import FORMAT, OnnxActor

    graph = helper.make_graph(
        [helper.make_node("Identity", ["node_mask"], ["masked_logits"]),
         helper.make_node("ArgMax", ["node_mask"], ["action"], axis=1, keepdims=0)], "g",
        [helper.make_tensor_value_info("node_mask", TensorProto.FLOAT, [None, 4]),
         helper.make_tensor_value_info("action_mask", TensorProto.BOOL, [None, 4])],
        [helper.make_tensor_value_info("masked_logits", TensorProto.FLOAT, [None, 4]),
         helper.make_tensor_value_info("action", TensorProto.INT64, [None])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    helper.set_model_props(model, {"format": FORMAT, "observation_keys": '["node_mask"]'})
    onnx.save(model, tmp_path / "m.onnx")
    actor = OnnxActor(tmp_path / "m.onnx")
    assert actor({"node_mask": np.ones(4)}, np.ones(4, bool))[1][0] == 0
    with pytest.raises(UserInputError, match="lacks node_mask: this model takes node_mask"):
        actor({"map": np.ones(4)}, np.ones(4, bool))


# ------------------------------------------------------------------ empty lists, suffixes

@pytest.mark.parametrize("flag,value", [("--explorers", ""), ("--scenes", " , ")])
def test_bench_refuses_an_empty_list(tmp_path, capsys, flag, value):
    err = refused(["bench", flag, value, "--out", str(tmp_path / "b")], tmp_path, capsys)
    assert f"{flag} {value!r} names nothing" in err


@pytest.mark.parametrize("args", [
    ["explore", "--video", "{p}/v.avi"],
    ["explore", "--video", "{p}/missing/v.mp4"],
    ["render", "{p}", "--out", "{p}/v.avi"]])
def test_videos_are_mp4_files_in_existing_folders(tmp_path, capsys, args):
    args = [a.format(p=tmp_path) for a in args]
    if args[0] == "explore":
        args += ["--scene", "train_loop", "--out", str(tmp_path / "o")]
    err = refused(args, tmp_path, capsys)
    assert ".mp4" in err or "does not exist" in err


@pytest.mark.parametrize("args,message", [
    (["{p}/step.pt", "{p}/x.onnx"], "give OUT ending in .safetensors"),
    (["--onnx", str(MODELS_DIR / "gvn_v3" / "policy.safetensors"), "{p}/x.safetensors"],
     "give OUT ending in .onnx"),
    (["--onnx", str(MODELS_DIR / "gvn_v3" / "policy.safetensors"), "/proc/x.onnx"],
     "choose a folder you can write to")])
def test_export_policy_writes_only_the_format_its_out_names(tmp_path, args, message):
    (tmp_path / "step.pt").write_bytes(b"not read")
    before = listing(tmp_path)
    r = subprocess.run([sys.executable, "-m", "mjexplore.cli", "export-policy",
                        *[a.format(p=tmp_path) for a in args]], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and message in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not r.stdout
    assert listing(tmp_path) == before


# ------------------------------------------------------------------ help

def test_help_shows_every_default():
    """Every option that takes a value says its default (flags are off unless given)."""
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    silent = []
    for name, command in commands.choices.items():
        formatter = command._get_formatter()
        for action in command._actions:
            if (not action.option_strings or action.required or action.nargs == 0
                    or action.dest == "help"):
                continue
            if "default" not in formatter._expand_help(action):
                silent.append(f"{name} {action.option_strings[0]}")
    assert not silent
    assert "office scene" in commands.choices["explore"].format_help()
    assert "36" in " ".join(commands.choices["bench"].format_help().split())


# ------------------------------------------------------------------ weights are checked

def _damaged_copy(source: Path, target: Path) -> Path:
    """``source`` with bytes flipped in its first tensor, header intact."""
    blob = bytearray(source.read_bytes())
    data = 8 + int.from_bytes(blob[:8], "little")
    blob[data + 64:data + 72] = bytes(b ^ 0xFF for b in blob[data + 64:data + 72])
    target.write_bytes(bytes(blob))
    return target


def test_damaged_shipped_weights_are_refused(tmp_path, capsys):
    (tmp_path / "inputs").mkdir()
    weights = _damaged_copy(MODELS_DIR / "gvn_v3" / "policy.safetensors",
                            tmp_path / "inputs" / "v3.safetensors")
    err = refused(["explore", "--explorer", "gvn_v3", "--policy", str(weights), "--out",
                   str(tmp_path / "o")], tmp_path, capsys)
    assert "are damaged (their checksum does not match" in err and "gvn_v3" in err


def test_damaged_trained_weights_are_refused(tmp_path):
    from mjexplore.policies.models import weights_metadata
    from mjexplore.policies.weights import (
        load_policy,
        read_policy_weights,
        save_policy_weights,
        tensors_sha256,
    )

    policy, meta = load_policy(MODELS_DIR / "gvn_paper" / "policy.safetensors")
    path = tmp_path / "mine.safetensors"
    save_policy_weights(path, policy, "gvn", meta["policy_kwargs"], meta["layout"])
    tensors, _ = read_policy_weights(path)  # Intact: read and checked.
    assert tensors_sha256(tensors) == weights_metadata(path)["tensors_sha256"]
    with pytest.raises(UserInputError, match="damaged .their checksum does not match.: "
                                             "re-export them"):
        load_policy(_damaged_copy(path, tmp_path / "bad.safetensors"))


def test_cnn_weights_given_to_gvn_name_the_cnn_explorer(tmp_path, capsys):
    (tmp_path / "inputs").mkdir()
    weights = tmp_path / "inputs" / "c.safetensors"
    shutil.copy(MODELS_DIR / "cnn_v2" / "policy.safetensors", weights)
    for explorer in ("gvn", "gvn_v3"):
        err = refused(["explore", "--explorer", explorer, "--policy", str(weights), "--out",
                       str(tmp_path / "o")], tmp_path, capsys)
        assert "cnn" in err and f"--explorer cnn --policy {weights}" in err


def test_another_recipe_for_a_model_label_is_refused(tmp_path, capsys):
    (tmp_path / "inputs").mkdir()
    weights = tmp_path / "inputs" / "v2.safetensors"
    shutil.copy(MODELS_DIR / "gvn_v2" / "policy.safetensors", weights)
    err = refused(["explore", "--explorer", "gvn_v3", "--policy", str(weights), "--out",
                   str(tmp_path / "o")], tmp_path, capsys)
    assert "(gvn v2, masking iam)" in err and f"--explorer gvn --policy {weights}" in err


def test_metrics_record_the_policys_recipe_and_hash(tmp_path):
    weights = tmp_path / "mine.safetensors"
    shutil.copy(MODELS_DIR / "gvn_paper" / "policy.safetensors", weights)
    assert main(["explore", "--scene", "train_loop", "--explorer", "gvn", "--policy",
                 str(weights), "--max-time", "2", "--no-mcap", "--out",
                 str(tmp_path / "o")]) == 0
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["policy_recipe"] == "gvn.yaml (gvn v1, masking iam)"
    assert metrics["weights_sha256"] == "1a64c4fef1f6bc4b"


# ------------------------------------------------------------------ long work in a pipe

def test_train_in_a_pipe_writes_lines_not_bars(tmp_path):
    config = tiny_config(tmp_path, total=10)
    config.write_text(config.read_text().replace("every: 0", "every: 1000, procedural: "
                                                 "{families: [maze]}"))
    r = subprocess.run([sys.executable, "-m", "mjexplore.cli", "train", "--config",
                        str(config), "--out", str(tmp_path / "run")], capture_output=True,
                       text=True, timeout=240, env={**os.environ, "COLUMNS": "100"})
    assert r.returncode == 0, r.stderr
    assert "\r" not in r.stderr
    lines = r.stderr.splitlines()
    assert any("10 more decision steps asked, 16 trained" in line for line in lines)
    assert any(line.startswith("train: 16/16 decisions (100%), done") for line in lines)
    assert any("no held-out evaluation ran" in line for line in lines)
    assert json.loads(r.stdout.splitlines()[-1])["num_timesteps"] == 16


def test_export_policy_writes_an_onnx_model_from_the_cli(tmp_path, capsys):
    from mjexplore.cli import main

    out = tmp_path / "gvn.onnx"
    assert main(["export-policy", "--onnx", str(MODELS_DIR / "gvn_v3" / "policy.safetensors"),
                 str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["kind"] == "gvn" and printed["outputs"] == ["masked_logits", "action"]
    assert out.stat().st_size > 1000 and listing(tmp_path) == ["gvn.onnx"]
