"""Property-based tests: malformed input ends in a clean UserInputError or a valid result.

Random YAML (text, documents, and single settings of the shipped recipes changed) as the
training, predictor-training and pocket-training configs (there is no scene config:
scenes come from the generators' arguments, covered below, or from map_server maps);
random small map_server maps (PGM bytes and a YAML of random resolution, origin,
thresholds and mode) through the importer (``resolve_scene`` of the YAML); and random
values of the numeric command-line options, through argument parsing and the commands'
validators only (no episode runs). Whatever a loader refuses, the command line refuses as
well: exit code 2, one stderr line, no traceback, nothing under --out.

The budget is fixed (``derandomize``: the same examples every run; about 25 s in all); the
``@example``s are inputs that once escaped as tracebacks, printed warnings beside the error,
or were accepted although they make no sense (NaN, infinity, a 20,000 km map).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import math
import os
import tempfile
import warnings
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from mjexplore import cli
from mjexplore.cli import main
from mjexplore.config import to_dict
from mjexplore.errors import UserInputError
from mjexplore.learning.pocket_training import PocketTrainingConfig, load_pocket_config
from mjexplore.learning.predictor_training import PredictorTrainingConfig, load_predictor_config
from mjexplore.learning.train_config import TrainConfig, load_train_config
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.scene import SceneFiles, check_start

ROOT = Path(__file__).resolve().parents[1]
_FUZZ = settings(deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.function_scoped_fixture,
                                        HealthCheck.too_slow])
# More examples for a bug hunt: MJEXPLORE_FUZZ_SCALE=20 (the tests' budget is scale 1).
SCALE = float(os.environ.get("MJEXPLORE_FUZZ_SCALE", "1"))


def fuzz(examples: int) -> settings:
    """The fixed budget of one test: ``examples`` derandomized examples, no deadline."""
    return settings(_FUZZ, max_examples=max(1, int(examples * SCALE)))

_case = itertools.count()


def fresh(tmp_path: Path) -> Path:
    """A new empty folder for one example (the fixture's folder is shared by all)."""
    folder = tmp_path / f"case{next(_case)}"
    folder.mkdir()
    return folder


def assert_refused(capsys, argv: list[str], out: Path) -> None:
    """``argv`` exits with code 2 and one stderr line, no traceback, nothing at ``out``."""
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # Argument errors exit from argparse.
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, (argv, err)
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and err.startswith("mjexplore")
    assert not out.exists(), f"{argv} wrote {out}"


# ------------------------------------------------------------------------ configs

LOADERS = {
    "train": (load_train_config, TrainConfig, ROOT / "training" / "gvn_v3.yaml"),
    "train-predictor": (load_predictor_config, PredictorTrainingConfig,
                        ROOT / "training" / "predictor.yaml"),
    "train-pockets": (load_pocket_config, PocketTrainingConfig,
                      ROOT / "training" / "pockets.yaml"),
}
_BASES: dict[str, dict] = {}


def base_settings(command: str) -> dict:
    """The shipped recipe's resolved settings, as a YAML mapping."""
    if command not in _BASES:
        load, _, path = LOADERS[command]
        _BASES[command] = to_dict(load(path))
    return _BASES[command]


SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-3, 3), st.integers(-(2**70), 2**70),
    st.floats(-2.0, 2.0), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=6),
    st.sampled_from(["gvn", "cnn", "ter", "grid", "v3", "iam", "none", "nearest", "office",
                     "maze", "1e3", "", "\x00"]))
VALUES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=3)
                      | st.dictionaries(st.text(max_size=5), inner, max_size=3),
                      max_leaves=6)
YAML_LINES = st.sampled_from([
    "a: 1", "- x", "{", "}", "[1, 2", ":", "? x", "key: [1, {b: 2}]",
    "!!python/object:os.system {}",
    "&a [*a]", "*b", "\t- y", "kind: cnn", "ppo: {n_steps: 0}", "extends: missing.yaml",
    "extends: .", "extends: ''", "extends: [x]", "seed: -1", "1: 2", "null: 3", "--- !!set {a}",
    "%YAML 1.1", "...", "'unclosed", "\"\\x\"", "<<: {a: 1}", "episodes: .nan"])


@st.composite
def changed_recipe(draw, command: str) -> dict:
    """The shipped recipe with one setting (a leaf, at any depth) changed within its kind,
    replaced, removed, or with a key added beside it."""
    data = base_settings(command)
    path: list[str] = []
    node = data
    while isinstance(node, dict) and node:
        key = draw(st.sampled_from(sorted(node)))
        path.append(key)
        node = node[key]
    changed = _copy(data)
    parent = changed
    for key in path[:-1]:
        parent = parent[key]
    action = draw(st.sampled_from(["perturb"] * 4 + ["replace", "remove", "add"]))
    if action == "perturb":
        parent[path[-1]] = draw(perturbed(parent[path[-1]]))
    elif action == "add":
        parent[draw(st.text(min_size=1, max_size=6))] = draw(VALUES)
    elif action == "remove":
        del parent[path[-1]]
    else:
        parent[path[-1]] = draw(VALUES)
    return changed


def perturbed(value):
    """Values of the same kind as ``value``: where a recipe's checks decide."""
    if isinstance(value, bool):
        return st.booleans() | VALUES
    if isinstance(value, int):
        return st.integers(-2, 4) | st.integers(-(2**63), 2**63)
    if isinstance(value, float):
        return (st.floats(-1.0, 2.0) | st.floats(allow_nan=True, allow_infinity=True)
                | st.integers(-1, 2))
    if isinstance(value, str):
        return st.sampled_from(["", value + "x", value.upper()]) | st.text(max_size=6)
    if isinstance(value, list):
        return st.lists(st.sampled_from(value) if value else VALUES, max_size=len(value) + 1)
    return VALUES


def _copy(data):
    if isinstance(data, dict):
        return {k: _copy(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_copy(v) for v in data]
    return data


def config_documents(command: str):
    """Bytes of a config file: random text, random lines of YAML, random YAML documents,
    and the shipped recipe with one setting changed (on its own or over ``extends``)."""
    recipe = LOADERS[command][2]
    return st.one_of(
        changed_recipe(command).map(lambda d: yaml.safe_dump(d).encode()),
        st.dictionaries(st.sampled_from(sorted(base_settings(command))), VALUES, min_size=1,
                        max_size=2).map(lambda d: yaml.safe_dump(
                            {"extends": str(recipe), **d}).encode()),
        st.binary(max_size=40),
        st.text(max_size=60).map(str.encode),
        st.lists(YAML_LINES, max_size=5).map(lambda lines: "\n".join(lines).encode()),
        VALUES.map(lambda v: yaml.safe_dump(v).encode()),
    )


def check_config(command: str, text: bytes, tmp_path: Path, capsys) -> None:
    load, cls, _ = LOADERS[command]
    folder = fresh(tmp_path)
    path = folder / "config.yaml"
    path.write_bytes(text)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # The CLI would print them.
            config = load(path)
    except UserInputError as exc:
        event("refused")
        assert str(exc).strip()
        out = folder / "out"
        assert_refused(capsys, [command, "--config", str(path), "--out", str(out)], out)
        return
    event("loaded")
    assert isinstance(config, cls)  # A valid config: not run (that would train).
    saved = folder / "saved.yaml"  # As a run saves it, for --resume.
    saved.write_text(yaml.safe_dump(to_dict(config)))
    assert load(saved) == config


@fuzz(150)
@given(text=config_documents("train"))
@example(text=b"kind: \xff\xfe\n")  # Not UTF-8: a UnicodeDecodeError escaped.
@example(text=b"1: 2\na: 3\n")  # Mixed key types: sorting them raised TypeError.
@example(text=b"extends: \"a\\0b\"\n")  # A NUL in a path: ValueError escaped.
@example(text=yaml.safe_dump({"extends": str(ROOT / "training" / "gvn_v3.yaml"),
                              "ppo": {"learning_rate": math.nan}}).encode())  # Was accepted.
def test_training_configs(text, tmp_path, capsys):
    check_config("train", text, tmp_path, capsys)


@fuzz(100)
@given(text=config_documents("train-predictor"))
@example(text=yaml.safe_dump({"extends": str(ROOT / "training" / "predictor.yaml"),
                              "learning_rate": math.inf}).encode())  # Was accepted.
def test_predictor_configs(text, tmp_path, capsys):
    check_config("train-predictor", text, tmp_path, capsys)


@fuzz(60)
@given(text=config_documents("train-pockets"))
def test_pocket_configs(text, tmp_path, capsys):
    check_config("train-pockets", text, tmp_path, capsys)


@fuzz(150)
@given(data=st.data(), command=st.sampled_from(sorted(LOADERS)))
def test_changed_recipes(data, command, tmp_path, capsys):
    """Every shipped recipe with one setting changed, where the checks of each section
    decide (most random documents stop at the first key)."""
    text = yaml.safe_dump(data.draw(changed_recipe(command))).encode()
    check_config(command, text, tmp_path, capsys)


# ------------------------------------------------------------------------ maps

NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5),
                    st.booleans(), st.none(), st.text(max_size=4),
                    st.sampled_from([0.05, 0.1, 0.5, 1e-9, 1e9, 1e300, math.inf, math.nan,
                                     2**1100, "0.1", [0.1]]))


@st.composite
def pgm_bytes(draw) -> bytes:
    """A small PGM: free, with a few pixels of other values, or random throughout; now and
    then of another depth, with a damaged header, or truncated."""
    w, h = draw(st.integers(1, 40)), draw(st.integers(1, 40))
    if draw(st.integers(0, 3)):
        pixels = bytearray([254]) * (w * h)
        for _ in range(draw(st.integers(0, 12))):
            pixels[draw(st.integers(0, w * h - 1))] = draw(
                st.sampled_from([0, 205, 255, 128, 50]) | st.integers(0, 255))
    else:
        pixels = bytearray(draw(st.binary(min_size=w * h, max_size=w * h)))
    maxval = draw(st.sampled_from([255] * 8 + [100, 1, 0, 65535]))
    if maxval > 255:
        pixels = bytearray(b for p in pixels for b in (0, p))
    if draw(st.integers(0, 7)):
        header = f"P5\n{w} {h}\n{maxval}\n".encode()
    else:
        header = draw(st.sampled_from([b"P2\n1 1\n255\n7\n", b"P5\n", b"P6\n2 2\n255\n",
                                       b"", b"P5\n-3 4\n255\n", b"GIF89a"]))
    data = header + bytes(pixels)
    if not draw(st.integers(0, 9)):  # Truncated.
        data = data[:draw(st.integers(0, len(data)))]
    return data


@st.composite
def map_yaml(draw) -> dict:
    """A map_server YAML: map_saver's, with up to three entries changed or left out."""
    meta = {"image": "map.pgm", "resolution": draw(st.sampled_from([0.05, 0.1, 0.2])),
            "origin": draw(st.sampled_from([[0.0, 0.0, 0.0], [-3.0, 2.5, 0.0]])),
            "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196, "mode": "trinary"}
    changes = {
        "image": st.sampled_from(["missing.pgm", "", ".", "map.pgm\x00"]) | st.text(max_size=4),
        "resolution": NUMBERS, "origin": st.lists(NUMBERS, max_size=4) | NUMBERS,
        "negate": NUMBERS, "occupied_thresh": NUMBERS, "free_thresh": NUMBERS,
        "mode": st.sampled_from(["scale", "raw", "other", 3]) | NUMBERS}
    for key in draw(st.sets(st.sampled_from(sorted(meta)), max_size=3)):
        if draw(st.integers(0, 3)):
            meta[key] = draw(changes[key])
        else:
            del meta[key]
    return meta


OPEN_PGM = b"P5\n20 20\n255\n" + bytes([254]) * 400  # 2 x 2 m free at 0.1 m.
MAP_SAVER = {"image": "map.pgm", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0,
             "occupied_thresh": 0.65, "free_thresh": 0.196}


@pytest.fixture
def import_cache(tmp_path, monkeypatch):
    """Imported maps go under the test's folder, not the system's temporary one."""
    cache = tmp_path / "tmp"
    cache.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(cache))
    return cache


@fuzz(60)
@given(image=pgm_bytes(), meta=map_yaml())
@example(image=OPEN_PGM, meta={**MAP_SAVER, "resolution": 2**1100})  # OverflowError.
@example(image=OPEN_PGM, meta={**MAP_SAVER, "origin": [2**1100, 0, 0]})  # OverflowError.
@example(image=OPEN_PGM, meta={**MAP_SAVER, "resolution": math.inf})  # NumPy warnings.
@example(image=OPEN_PGM, meta={**MAP_SAVER, "origin": [1e308, 0.0, 0.0]})  # NumPy warnings.
@example(image=OPEN_PGM, meta={**MAP_SAVER, "resolution": 1e9})  # Was imported: 20,000 km.
@example(image=OPEN_PGM, meta=MAP_SAVER)
def test_imported_maps(image, meta, tmp_path, import_cache, capsys):
    folder = fresh(tmp_path)
    (folder / "map.pgm").write_bytes(image)
    path = folder / "map.yaml"
    path.write_text(yaml.safe_dump(meta))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # The CLI would print them.
            scene = resolve_scene(path)
    except UserInputError:
        event("refused")
        out = folder / "out"
        assert_refused(capsys, ["explore", "--scene", str(path), "--out", str(out)], out)
        return
    event("imported")
    assert isinstance(scene, SceneFiles) and scene.xml.is_file()
    assert scene.ground_truth is not None and scene.ground_truth.free.any()
    assert all(math.isfinite(v) for v in scene.start)
    check_start(scene.ground_truth, scene.start)


# ------------------------------------------------------------------------ options

OPTION_TEXT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**30), 10**30).map(str),
    st.sampled_from(["nan", "inf", "-inf", "-0", "0", "1", "0.5", "1e-300", "1e308", "1e999",
                     "0x10", "1_000", " 5", "\uff15", "\u00b2", "", "--", "2x", "3x4",
                     "infx480", "640xnan", "1,2", "nan,1", "1e400,0"]),
    st.text(max_size=5))

# (command, option, other arguments, the value's contract when it is accepted).
OPTIONS = [
    ("explore", "--max-time", [], lambda a: 0 < a.max_time < math.inf),
    ("explore", "--lidar-range", [], lambda a: 0 < a.lidar_range < math.inf),
    ("explore", "--target-ratio", [], lambda a: 0 < a.target_ratio <= 1),
    ("explore", "--seed", [], lambda a: a.seed >= 0),
    ("explore", "--lidar-noise", [], lambda a: 0 <= a.lidar_noise < math.inf),
    ("explore", "--robots", [], lambda a: a.robots >= 1),
    ("explore", "--live", [], lambda a: 0 <= a.live <= 65535),
    ("explore", "--live-rate", ["--live"], lambda a: 0 < a.live_rate < math.inf),
    ("explore", "--video-size", ["--video={folder}/v.mp4"],
     lambda a: all(v % 2 == 0 and 16 <= v < math.inf for v in a.video_size)),
    ("explore", "--video-fps", ["--video={folder}/v.mp4"], lambda a: 0 < a.video_fps < math.inf),
    ("bench", "--seeds", [], lambda a: a.seeds >= 1),
    ("bench", "--workers", [], lambda a: a.workers >= 1),
    ("bench", "--max-time", [], lambda a: 0 < a.max_time < math.inf),
    ("scene-gen", "--size", ["maze"], lambda a: all(0 < v < math.inf for v in a.size)),
    ("scene-gen", "--start", ["--from-map", "x.yaml"],
     lambda a: all(math.isfinite(v) for v in a.start)),
    ("train", "--total-steps", ["--config", "x.yaml"], lambda a: a.total_steps >= 1),
]


def validate(args: argparse.Namespace) -> None:
    """What the command checks of its options before it starts work (its validators, or
    their conditions), without the work."""
    if args.command == "explore":
        cli._episode_config(args)
        if args.video is not None:
            cli._video_config(args)
    elif args.command == "bench":
        cli._episode_config(args)
        if args.workers < 1 or args.seeds < 1:
            raise UserInputError("--workers and --seeds must be at least 1.")


@fuzz(250)
@given(option=st.sampled_from(OPTIONS), value=OPTION_TEXT)
@example(option=OPTIONS[8], value="infx480")  # int(inf): an OverflowError escaped.
@example(option=OPTIONS[1], value="inf")  # An infinite lidar "explored" at once.
@example(option=OPTIONS[4], value="nan")  # Was accepted.
@example(option=OPTIONS[6], value="\u00b2")  # isdigit() but not int(): argparse's
def test_numeric_options(option, value, tmp_path, capsys):  # "invalid _port value".
    command, flag, extra, contract = option
    folder = fresh(tmp_path)
    out = folder / "out"
    argv = [command, *(e.format(folder=folder) for e in extra), f"{flag}={value}", "--out",
            str(out)]
    capsys.readouterr()
    try:
        args = cli.build_parser().parse_args(argv)
    except SystemExit as exc:
        event("refused by the parser")
        err = capsys.readouterr().err
        assert exc.code == 2 and len(err.strip().splitlines()) == 1, err
        assert "--help" in err and "invalid _" not in err, err  # No private names.
        assert not out.exists()
        return
    try:
        with contextlib.redirect_stdout(None), warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            validate(args)
    except UserInputError:
        event("refused by the validators")
        if command in ("explore", "bench"):
            assert_refused(capsys, argv, out)
        return
    event("accepted")
    assert contract(args), (flag, value)
