"""The ``mjexplore`` command line: thin commands that build a config and call the library.

Every command answers bad input with a one-paragraph message on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import json
import logging
import math
import os
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import check_output_file, check_output_folder

log = logging.getLogger("mjexplore")

DEFAULT_SCENE_SIZE = (40.0, 25.0)  # Generated scenes, metres (the paper's office).
# bench's defaults: the paper's Table 1 scenes and the classic explorers.
BENCH_SCENES = "loop_with_corridor,maze,office"
BENCH_EXPLORERS = "nearest,rrt,potential,oracle"
BENCH_SEEDS = 3


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, unless the help says it already or there
    is none to say (flags, required options, None)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if ("default" in text or action.required or not action.option_strings
                or any(action.default is v for v in (None, False, argparse.SUPPRESS))):
            return text
        return text + " (default: %(default)s)"


def _size(text: str) -> tuple[float, float]:
    try:
        w, h = (float(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r} is not WIDTHxHEIGHT in metres, "
                                         "e.g. 40x25") from None
    if not (0 < w < math.inf and 0 < h < math.inf):
        raise argparse.ArgumentTypeError(f"size {text!r} must be positive and finite, e.g. "
                                         "40x25")
    return w, h


def _pose(text: str) -> tuple[float, float, float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(f"pose {text!r} is not X,Y[,YAW] in metres and "
                                         "radians (finite numbers)")
    return (values[0], values[1], values[2] if len(values) == 3 else 0.0)


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive finite number")
    return value


def _port(text: str) -> int:
    if not (text.isascii() and text.isdigit()) or not 0 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(f"port {text!r} is not a TCP port (0 to 65535; 0 "
                                         "takes a free one)")
    return int(text)


def _whole(what: str, least: int):
    """An argument type: a whole number >= ``least``, named ``what`` in errors."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what}{text!r} is not a whole number") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"{what}{text!r} must be a whole number >= {least}")
        return value

    return parse


_seed = _whole("seed ", 0)
_count = _whole("", 1)


def cmd_scene_gen(args: argparse.Namespace) -> int:
    from mjexplore.scenes.canonical import CANONICAL_SCENES
    from mjexplore.scenes.generators import FAMILIES, GeneratorConfig
    from mjexplore.scenes.scene import write_scene

    if args.list:
        print("families:", ", ".join(sorted(FAMILIES)), "(combine with '+', e.g. loop+rooms)")
        for name, c in CANONICAL_SCENES.items():
            print(f"{name:24s} {c.role:5s} {c.family:22s} {c.size[0]:g}x{c.size[1]:g} m  "
                  f"seed {c.seed}  {c.note}")
        return 0
    if args.from_scene is not None:
        return _export_existing_scene(args)
    if args.out is None:
        raise UserInputError("scene-gen needs --out DIR: the folder to write the scene to.")
    check_output_folder(args.out)
    if args.export is not None:
        from mjexplore.scenes.mesh import check_export_path

        check_export_path(args.export)  # Before the work, not after it.
    mesh_options = [f"--{o.replace('_', '-')}" for o in MESH_OPTIONS
                    if getattr(args, o) is not None]
    if mesh_options and args.from_mesh is None:
        raise UserInputError(f"{', '.join(mesh_options)} apply to --from-mesh only.")
    if args.from_mesh is not None:
        scene = _mesh_scene(args)
    elif args.from_map is not None:
        if args.family is not None:
            raise UserInputError("give either a FAMILY or --from-map, not both.")
        if args.size is not None or args.wall_thickness is not None:
            raise UserInputError("--size and --wall-thickness apply to generated scenes; an "
                                 "imported map has its own size and walls.")
        from mjexplore.scenes.importer import scene_from_image, scene_from_map_yaml

        path = Path(args.from_map)
        if path.suffix.lower() in (".yaml", ".yml"):
            if args.resolution is not None:
                raise UserInputError("--resolution applies to an image; a map_server YAML "
                                     "gives its own resolution.")
            scene = scene_from_map_yaml(path, start=args.start, seed=args.seed)
        else:
            if args.resolution is None:
                raise UserInputError(f"{str(path)!r} is an image, not a map_server YAML: give its "
                                     "scale with --resolution METRES_PER_PIXEL (e.g. 0.1).")
            scene = scene_from_image(path, args.resolution, start=args.start, seed=args.seed)
        if args.name is not None:
            scene = dataclasses.replace(scene, name=args.name)
    else:
        if args.family is None:
            raise UserInputError("scene-gen needs a FAMILY (e.g. office), --from-map MAP.yaml or "
                                 "--from-mesh FILE.glb; see 'mjexplore scene-gen --list'.")
        from mjexplore.scenes.generate import generate_scene

        cfg = (GeneratorConfig() if args.wall_thickness is None else
               GeneratorConfig(wall_thickness=args.wall_thickness))
        width, height = args.size or DEFAULT_SCENE_SIZE
        scene = generate_scene(args.family, width, height, seed=args.seed,
                               resolution=args.resolution or 0.05, config=cfg, name=args.name)
        if args.start is not None:
            raise UserInputError("--start applies to --from-map and --from-mesh; generated "
                                 "scenes pick their own start from the seed.")
    xml = write_scene(scene, args.out)
    summary = {"scene": str(xml), "start": list(scene.start),
               "wall_boxes": int(len(scene.wall_boxes()))}
    if args.export is not None:
        from mjexplore.scenes.mesh import export_scene_mesh

        summary["export"] = str(export_scene_mesh(xml, args.export))
    print(json.dumps(summary))
    return 0


MESH_OPTIONS = ("mesh_units", "mesh_scale", "up_axis", "floor_z", "height")


def _mesh_scene(args: argparse.Namespace):
    if args.family is not None or args.from_map is not None:
        raise UserInputError("give one of FAMILY, --from-map and --from-mesh.")
    if args.size is not None or args.wall_thickness is not None:
        raise UserInputError("--size and --wall-thickness apply to generated scenes; a mesh "
                             "has its own size and walls.")
    if args.mesh_units is not None and args.mesh_scale is not None:
        raise UserInputError("give --mesh-units or --mesh-scale, not both.")
    from mjexplore.scenes.mesh import MeshImportConfig, scene_from_mesh, units_scale

    config = MeshImportConfig(scale=args.mesh_scale or units_scale(args.mesh_units or "m"),
                              up_axis=args.up_axis, floor_z=args.floor_z, height=args.height,
                              resolution=args.resolution or 0.05)
    return scene_from_mesh(args.from_mesh, config, start=args.start, seed=args.seed,
                           name=args.name)


def _export_existing_scene(args: argparse.Namespace) -> int:
    if args.export is None:
        raise UserInputError("--from-scene writes an existing scene as a mesh: add --export "
                             "FILE.glb.")
    given = [o for o, v in (("FAMILY", args.family), ("--from-map", args.from_map),
                            ("--from-mesh", args.from_mesh), ("--out", args.out)) if v is not None]
    if given:
        raise UserInputError(f"--from-scene exports a scene and makes none: drop "
                             f"{', '.join(given)}.")
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.scenes.mesh import export_scene_mesh

    xml = resolve_scene(args.from_scene).xml
    print(json.dumps({"scene": str(xml), "export": str(export_scene_mesh(xml, args.export))}))
    return 0


def _lidar_config(args: argparse.Namespace, ideal_noise: float):
    """The lidar of --lidar-model, --lidar-range and --lidar-noise (``ideal_noise`` when
    the ideal model is given none)."""
    from mjexplore.robot import motion_profile
    from mjexplore.sim.lidar import lidar_model

    if args.lidar_model == "ideal":
        noise = ideal_noise if args.lidar_noise is None else args.lidar_noise
        return lidar_model("ideal", noise_std=noise,
                           range_max=args.lidar_range or motion_profile(args.profile).lidar_range)
    if args.lidar_noise is not None:
        raise UserInputError("--lidar-noise sets the ideal lidar's noise, and --lidar-model "
                             f"{args.lidar_model} has its unit's range-dependent noise: drop "
                             "--lidar-noise, or use --lidar-model ideal.")
    return lidar_model(args.lidar_model, **(
        {} if args.lidar_range is None else {"range_max": args.lidar_range}))


def cmd_drive(args: argparse.Namespace) -> int:
    from mjexplore.eval.drive import DriveConfig, run_drive
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.simulator import SimConfig

    check_output_folder(args.out)
    lidar = _lidar_config(args, ideal_noise=0.0)
    config = DriveConfig(duration=args.duration, seed=args.seed,
                         sim=SimConfig(profile=args.profile, lidar=lidar, seed=args.seed))
    summary = run_drive(resolve_scene(args.scene), config, args.out)
    print(json.dumps(summary))
    return 0


def _episode_config(args: argparse.Namespace):
    from mjexplore.episode import EpisodeConfig
    from mjexplore.sim.simulator import SimConfig

    if not 0 < args.target_ratio <= 1:
        raise UserInputError(f"--target-ratio {args.target_ratio} must be in (0, 1].")
    from mjexplore.sim.people import PeopleConfig

    lidar = _lidar_config(args, ideal_noise=0.01)
    if args.people and args.people_density:
        raise UserInputError("give --people N or --people-density D, not both.")
    people = PeopleConfig(count=args.people) if args.people else \
        PeopleConfig(density=args.people_density) if args.people_density else None
    return EpisodeConfig(max_time=args.max_time, target_ratio=args.target_ratio,
                         localization=args.localization,
                         sim=SimConfig(profile=args.profile, lidar=lidar,
                                       odometry_error=args.odometry_error,
                                       odometry_heading=args.odometry_heading, people=people))


def _team_config(args: argparse.Namespace):
    """The team settings of ``--unknown-starts`` (None: the defaults)."""
    from mjexplore.episode.team import TeamConfig

    if not args.unknown_starts:
        return None
    if args.robots < 2:
        raise UserInputError("--unknown-starts merges the maps of a team: add --robots 2 "
                             "or more.")
    return TeamConfig(unknown_starts=True)


def _explore_method(args: argparse.Namespace) -> str:
    """The method spec ``explore`` runs: ``--explorer`` with ``--policy`` and
    ``--no-masking`` applied (a learned explorer's), or a team method's name."""
    from mjexplore.eval.methods import LEARNED, MethodSpec, parse_method
    from mjexplore.explorers.team import TEAM_METHODS

    if args.explorer in TEAM_METHODS:
        if args.robots < 2:
            raise UserInputError(f"--explorer {args.explorer} coordinates a team: add --robots "
                                 "2 or more, or choose a single-robot explorer.")
        if args.policy is not None or args.no_masking:
            raise UserInputError("--policy and --no-masking apply to the learned explorers "
                                 f"only, not {args.explorer!r}.")
        return args.explorer
    spec = parse_method(args.explorer)
    if args.policy is not None or args.no_masking:
        if spec.method not in LEARNED:
            raise UserInputError("--policy and --no-masking apply to the learned explorers "
                                 f"only ({', '.join(LEARNED)}), not {args.explorer!r}.")
        if args.policy is not None and spec.policy is not None:
            _check_policy_fits_label(args.explorer, spec.method, spec.policy, args.policy)
        spec = MethodSpec(spec.method, args.policy or spec.policy,
                          False if args.no_masking else spec.masking)
    return spec.text


def cmd_explore(args: argparse.Namespace) -> int:
    from mjexplore.eval.methods import make_explorer, parse_method, team_explorers
    from mjexplore.eval.placements import team_starts
    from mjexplore.eval.run import RunInterrupted, write_run
    from mjexplore.scenes.canonical import resolve_scene

    try:
        spec = _explore_method(args)
        team_config = _team_config(args)
        check_output_folder(args.out)
        if args.video is not None:
            _check_video_path(Path(args.video), Path(args.out))
        # Built now to fail early on a bad name or weights file.
        if args.robots > 1:
            label = team_explorers(spec, args.robots)[1]
        else:
            explorer = make_explorer(spec)
            label = getattr(explorer, "label", parse_method(spec).method)
        video = _video_config(args) if args.video is not None else None
        if video is not None:
            from mjexplore.render.gl import check_rendering

            check_rendering()  # Fails now, not after the episode, if GL cannot load.
        scene, config = resolve_scene(args.scene), _episode_config(args)
        starts = team_starts(scene, args.starts, args.robots)
        with _live_server(args) as live:
            metrics = write_run(args.out, scene, label, args.seed, config, spec=spec,
                                mcap=False if args.no_mcap else args.mcap_profile or "foxglove",
                                video=video, video_path=args.video,
                                progress=not args.no_progress, live=live, robots=args.robots,
                                starts=starts, team_config=team_config)
    except KeyboardInterrupt as exc:  # Ctrl-C: say what was kept (see eval/run.py).
        kept = exc.kept if isinstance(exc, RunInterrupted) else []
        if not isinstance(exc, RunInterrupted) or not kept:
            said = f"nothing was kept: the run folder {str(args.out)!r}" + (
                f" and the video {args.video!r} were" if args.video is not None else " was"
            ) + " not written"
        else:
            m = exc.metrics
            assert m is not None  # Kept outputs come with their metrics (RunInterrupted).
            said = (f"the run folder {str(args.out)!r} is complete (end_reason {m['end_reason']!r} "
                    f"at {m['exploration_time_s']:g} s simulated)")
            if args.video is not None:
                upto = "up to then" if m["end_reason"] == "interrupted" else "whole"
                said += (f"; the video {args.video!r} holds the episode {upto}"
                         if Path(args.video) in kept else f"; no video {args.video!r} was kept")
        print(f"mjexplore explore: interrupted; {said}.", file=sys.stderr)
        return 130
    if args.video is not None:
        metrics["video"] = str(Path(args.video))
    print(json.dumps(metrics))
    return 0


def _check_policy_fits_label(label: str, kind: str, model: str, policy: str) -> None:
    """``--explorer LABEL`` names a shipped model (``model``, a ``kind`` policy) and
    ``--policy`` another policy: refused unless that policy is of the same recipe (kind,
    feature set, training masking), with the explorer that fits it."""
    from mjexplore.policies.models import describe_file, resolve_policy, weights_metadata

    _, path = resolve_policy(policy, kind)
    wanted, given = describe_file(resolve_policy(model, kind)[1]), describe_file(path)
    if wanted != given:
        theirs = weights_metadata(path).get("kind", kind)
        raise UserInputError(f"--explorer {label} runs the shipped model {model} ({wanted}), "
                             f"and --policy {policy!r} holds a policy of another recipe "
                             f"({given}): run it with --explorer {theirs} --policy {policy}.")


def _live_server(args: argparse.Namespace):
    """explore's Foxglove live server (a context manager), or a null context without --live."""
    if args.no_mcap and args.mcap_profile is not None:
        raise UserInputError("--mcap-profile applies to episode.mcap: drop --no-mcap or it.")
    if args.live is None:
        given = [o for o, v in (("--live-host", args.live_host), ("--live-rate", args.live_rate),
                                ("--live-wait", args.live_wait)) if v not in (None, False)]
        if given:
            raise UserInputError(f"{', '.join(given)}: settings of the live server, which "
                                 "runs only with --live (optionally with a port, e.g. "
                                 "--live 8765); add it or drop them.")
        return contextlib.nullcontext()
    from mjexplore.io.live import DEFAULT_HOST, LiveServer

    live = LiveServer(args.live_host or DEFAULT_HOST, args.live, rate=args.live_rate,
                      wait=args.live_wait)
    print(f"mjexplore explore: live at {live.url} (Foxglove: Open connection, Foxglove "
          "WebSocket)" + ("; the episode starts when Foxglove subscribes to a topic"
                          if args.live_wait else ""), file=sys.stderr, flush=True)
    return live


def _check_video_path(video: Path, out: Path) -> None:
    """Refuses a --video path that is not an MP4 or cannot be written. Its folder must exist,
    unless it is the run folder or the folder the run folder is made in (made anyway)."""
    if video.suffix.lower() != ".mp4":
        raise UserInputError(f"--video {str(video)!r}: the video is written as H.264 MP4: give "
                             "a file name ending in .mp4.")
    folder = video.parent.resolve()
    if folder in (out.resolve(), out.resolve().parent) and not folder.exists():
        check_output_folder(folder, "--video's folder")
        return
    check_output_file(video, "--video", (".mp4",))


def _video_config(args: argparse.Namespace):
    from mjexplore.render.recorder import VideoConfig

    w, h = args.video_size
    if int(w) != w or int(h) != h or w % 2 or h % 2 or w < 16 or h < 16:
        raise UserInputError(f"--video-size {w:g}x{h:g} must be even whole pixels, at least 16 "
                             "(e.g. 640x480).")
    return VideoConfig(width=int(w), height=int(h), fps=args.video_fps,
                       sim_seconds_per_frame=args.video_period)


def _add_video_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--video-size", type=_size, default=(640.0, 480.0), metavar="WxH",
                   help="size of each panel in pixels; the frame is two panels wide "
                   "(default: 640x480)")
    p.add_argument("--video-fps", type=_positive, default=20.0, help="video frame rate")
    p.add_argument("--video-period", type=_positive, default=1.0,
                   help="simulated seconds between frames (default: 1.0, 20x real time at "
                   "20 fps)")


def cmd_render(args: argparse.Namespace) -> int:
    from mjexplore.render.gl import check_rendering
    from mjexplore.render.replay import render_run

    out = check_output_file(args.out or Path(args.run_dir) / "video.mp4", "--out", (".mp4",))
    config = _video_config(args)
    check_rendering()
    print(json.dumps(render_run(args.run_dir, out, config, progress=not args.no_progress)))
    return 0


def cmd_export_policy(args: argparse.Namespace) -> int:
    suffix = Path(args.out).suffix.lower()
    if args.onnx and suffix != ".onnx":
        raise UserInputError(f"{args.out!r}: --onnx writes an ONNX model: give OUT ending in "
                             ".onnx.")
    if not args.onnx and suffix != ".safetensors":
        hint = (" To get an ONNX model, export the weights first, then run --onnx on them."
                if suffix == ".onnx" else "")
        raise UserInputError(f"{args.out!r}: a checkpoint exports as policy weights: give OUT "
                             f"ending in .safetensors.{hint}")
    check_output_file(args.out, "OUT")
    if args.onnx:
        if args.git_revision is not None:
            raise UserInputError("--git-revision applies to checkpoint exports; an ONNX "
                                 "export keeps the weights file's provenance.")
        if args.source.endswith(".pt"):
            raise UserInputError(f"{args.source!r} is a checkpoint: export its weights first "
                                 "(mjexplore export-policy CHECKPOINT policy.safetensors), "
                                 "then --onnx policy.safetensors.")
        from mjexplore.policies.onnx_export import export_onnx

        props = export_onnx(args.source, args.out)
        print(json.dumps({"out": args.out, "kind": props["kind"],
                          "weights_sha256": props["weights_sha256"],
                          "inputs": json.loads(props["observation_keys"]) + ["action_mask"],
                          "outputs": ["masked_logits", "action"]}))
        return 0
    from mjexplore.learning.checkpoints import export_checkpoint

    provenance = export_checkpoint(args.source, args.out, args.git_revision)
    print(json.dumps({"out": args.out, "num_timesteps": provenance["num_timesteps"],
                      "git_revision": provenance["git_revision"]}))
    return 0


def cmd_plot_training(args: argparse.Namespace) -> int:
    from mjexplore.eval.training_report import plot_training

    print(json.dumps(plot_training(args.run, args.out, workers=args.workers,
                                   baselines=not args.no_baselines,
                                   recompute=args.recompute_baselines,
                                   departures_of_shipped=args.departures,
                                   weights=args.weights)))
    return 0


def cmd_probe_policy(args: argparse.Namespace) -> int:
    from mjexplore.eval.probe import probe_policy

    print(json.dumps(probe_policy(args.weights, args.config, episodes=args.episodes,
                                  seed_base=args.seed_base, heldout=args.heldout,
                                  unseen=args.unseen, modes=args.modes.split(","),
                                  workers=args.workers)))
    return 0


def cmd_policies(args: argparse.Namespace) -> int:
    from mjexplore.policies.models import DEFAULT_MODEL, MODELS_DIR, shipped_models

    del args
    models = shipped_models()
    width = max(map(len, models))
    for name, m in models.items():
        default = f" (default for --explorer {m.kind})" if DEFAULT_MODEL[m.kind] == name else ""
        print(f"{name:<{width}}  {m.kind}  masking {m.masking:<5}  {m.summary}{default}")
    print(f"\nEach is a folder in {MODELS_DIR} (policy.safetensors, config.yaml, README.md); "
          "run one with 'mjexplore explore --explorer KIND --policy NAME'.")
    return 0


TEAM_BENCH_METHODS = "nearest,assign_greedy,assign_optimal,mmpf"


def _add_ray_argument(parser: argparse.ArgumentParser, what: str, default: str,
                      more: str = "") -> None:
    """The ``--ray [ADDRESS]`` option of the commands that run on a Ray cluster."""
    parser.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                        help=f"{what}: without ADDRESS on a local Ray instance on this "
                        "machine; with ADDRESS (auto, or the head's HOST:6379) on an existing "
                        "cluster started with `ray start --head` (guide: 'Scaling out')"
                        f"{more} (default: {default})")


MAX_SEEDS = 10_000  # A sweep's seeds; more is a typo, not an experiment.
MAX_WORKERS = 1_024


def _check_sweep_size(args: argparse.Namespace) -> None:
    """Refuses --seeds and --workers out of their bounds."""
    if not 1 <= args.seeds <= MAX_SEEDS or not 1 <= args.workers <= MAX_WORKERS:
        raise UserInputError(f"--seeds must be 1 to {MAX_SEEDS:,} and --workers 1 to "
                             f"{MAX_WORKERS:,} (a cluster's CPUs: --ray).")


def _refuse_repeats(lists: tuple[tuple[str, list[str]], ...]) -> None:
    """Refuses a name given twice in a sweep's list (it would run twice into one folder)."""
    for flag, names in lists:
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise UserInputError(f"{flag} names {', '.join(repeated)} more than once: each "
                                 "would run twice into the same run folders; name each once.")


def _bench_team(args: argparse.Namespace) -> int:
    """``bench --robots N``: a sweep of team episodes (eval/team_sweep.py)."""
    from mjexplore.eval.methods import team_explorers
    from mjexplore.eval.team_sweep import DRAWN, run_team_sweep

    text = args.explorers
    if text == BENCH_EXPLORERS:  # The single robot's default set.
        text = TEAM_BENCH_METHODS
    methods = [e.strip() for e in text.split(",") if e.strip()]
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    placements = [p.strip() for p in (args.starts or DRAWN).split(",") if p.strip()]
    if not methods or not scenes or not placements:
        raise UserInputError("--scenes, --explorers and --starts must each name one or more, "
                             "comma-separated.")
    _check_sweep_size(args)
    _refuse_repeats((("--scenes", scenes), ("--explorers", methods), ("--starts", placements)))
    if args.mcap is not None:
        raise UserInputError("a team sweep writes no MCAP: drop --mcap (explore --robots N "
                             "writes one).")
    for method in methods:
        team_explorers(method, args.robots)  # Fails early on a bad name.
    unknown_starts = _team_config(args) is not None
    check_output_folder(args.out)
    results = run_team_sweep(scenes, methods, args.robots, placements,
                             list(range(args.seeds)), Path(args.out), _episode_config(args),
                             workers=args.workers, unknown_starts=unknown_starts,
                             ray_address=args.ray, progress=not args.no_progress,
                             command=args.command_line)
    print((Path(args.out) / "results.md").read_text())
    return _failed_status(results)


def cmd_bench(args: argparse.Namespace) -> int:
    from mjexplore.eval.methods import parse_method
    from mjexplore.eval.sweep import run_sweep

    if args.robots > 1 or args.unknown_starts:
        return _bench_team(args)
    specs = [parse_method(e) for e in args.explorers.split(",") if e.strip()]
    explorers = [spec.label for spec in specs]
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    for flag, names, example in (("--scenes", scenes, BENCH_SCENES),
                                 ("--explorers", explorers, BENCH_EXPLORERS)):
        if not names:
            raise UserInputError(f"{flag} {getattr(args, flag[2:])!r} names nothing: give one "
                                 f"or more, comma-separated (e.g. {example}), or drop {flag} "
                                 "for its default.")
    _check_sweep_size(args)
    check_output_folder(args.out)
    _refuse_repeats((("--scenes", scenes), ("--explorers", explorers)))
    results = run_sweep(scenes, [spec.text for spec in specs], list(range(args.seeds)),
                        Path(args.out),
                        _episode_config(args), workers=args.workers, mcap=args.mcap,
                        command=args.command_line, progress=not args.no_progress,
                        ray_address=args.ray)
    print((Path(args.out) / "results.md").read_text())
    return _failed_status(results)


def _failed_status(results: list[dict]) -> int:
    """A sweep's exit status: 1 (and a line that says so) when an episode failed or was
    interrupted, else 0."""
    failed = [r for r in results if r.get("end_reason") in ("error", "interrupted")]
    if failed:
        print(f"{len(failed)} of {len(results)} episodes failed or were interrupted (listed "
              "under the table); a re-run with the same --out retries them.", file=sys.stderr)
        return 1
    return 0


def _check_device(text: str) -> None:
    """Refuses a ``--device`` torch cannot use here."""
    if text == "auto":
        return
    import torch

    try:
        device = torch.device(text)
    except RuntimeError:
        raise UserInputError(f"--device {text!r} is not a torch device: use auto, cpu, cuda "
                             "or cuda:N.") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise UserInputError(f"--device {text}: this machine has no CUDA GPU that torch can "
                             "use; use --device auto or cpu.")


def cmd_train(args: argparse.Namespace) -> int:
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.learning.training import train

    _check_device(args.device)

    config = load_train_config(args.config, total_steps=args.total_steps, n_envs=args.n_envs,
                               seed=args.seed)
    check_output_folder(args.out)
    summary = train(config, args.out, resume=args.resume, progress=not args.no_progress,
                    ray_address=args.ray, device=args.device, recipe=Path(args.config).name,
                    init_weights=args.init_weights)
    print(json.dumps(summary))
    return 0


def cmd_imitate(args: argparse.Namespace) -> int:
    from mjexplore.learning.dagger_run import imitate
    from mjexplore.learning.train_config import load_train_config

    config = load_train_config(args.config, seed=args.seed)
    if args.rounds is not None:
        config = dataclasses.replace(config, imitation=dataclasses.replace(
            config.imitation, dagger_iterations=args.rounds - 1))
    check_output_folder(args.out)
    record = imitate(config, args.out, resume=args.resume)
    last = record["rounds"][-1]
    print(json.dumps({"out": str(args.out), "rounds": len(record["rounds"]),
                      "decisions": record["decisions"],
                      "agreement_before": last["agreement_before"],
                      "weights": str(Path(args.out) / "policy.safetensors")}))
    return 0


def cmd_train_pockets(args: argparse.Namespace) -> int:
    from mjexplore.learning.pocket_training import load_pocket_config, train_pockets

    config = load_pocket_config(args.config)
    check_output_folder(args.out)
    if args.episodes is not None:
        config = dataclasses.replace(config, episodes=args.episodes)
    print(json.dumps(train_pockets(config, args.out, workers=args.workers,
                                   progress=not args.no_progress)))
    return 0


def cmd_train_predictor(args: argparse.Namespace) -> int:
    from mjexplore.learning.predictor_training import load_predictor_config, train_predictor

    config = load_predictor_config(args.config)
    check_output_folder(args.out)
    if args.episodes is not None:
        config = dataclasses.replace(config, episodes=args.episodes)
    if args.epochs is not None:
        config = dataclasses.replace(config, epochs=args.epochs)
    print(json.dumps(train_predictor(config, args.out, workers=args.workers,
                                     progress=not args.no_progress, ray_address=args.ray)))
    return 0


def cmd_collect(args: argparse.Namespace) -> int:
    from mjexplore.eval.experiments import EXPERIMENTS
    from mjexplore.eval.summaries import (
        collect_sweep,
        merge_summaries,
        read_summary,
        skipped_runs,
        write_summary,
    )

    known = [exp.name for exp in EXPERIMENTS]
    if args.experiment not in known:
        close = difflib.get_close_matches(args.experiment, known, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise UserInputError(f"--experiment {args.experiment!r} is not an experiment of the "
                             f"report: {hint}use one of {', '.join(known)}.")
    check_output_folder(args.data, "--data")
    if args.stills is not None:
        check_output_folder(args.figures, "--figures")
    _check_sweep_kind(args.sweep, args.experiment)
    summary = collect_sweep(args.sweep, args.experiment, command=args.sweep_command,
                            kinematics_series=args.kinematics, reference=args.reference,
                            stills=args.stills, media_dir=args.figures)
    path = args.data / f"{args.experiment}.json"
    if args.merge and path.is_file():
        summary = merge_summaries(summary, read_summary(path))
    path = write_summary(summary, path)
    skipped = skipped_runs(args.sweep)
    listed = {where for where, _ in skipped}
    skipped += [(where, "not run yet") for r in summary["unfinished"]["not_run"]
                if (where := f"runs/{r['scene']}/{r['method']}/seed{r['seed']}") not in listed]
    print(json.dumps({"summary": str(path), "runs": len(summary["runs"]),
                      "methods": sorted({r["method"] for r in summary["runs"]}),
                      "skipped": len(skipped)}))
    for where, why in skipped[:20]:
        print(f"mjexplore collect: skipped {where}: {why}", file=sys.stderr)
    if len(skipped) > 20:
        print(f"mjexplore collect: skipped {len(skipped) - 20} more", file=sys.stderr)
    return 1 if skipped and args.strict else 0


def _check_sweep_kind(sweep: Path, experiment: str) -> None:
    """Refuses a team sweep (``bench --robots``) filed as a single-robot experiment, and
    the other way round: the report would lay it out as the other kind."""
    from mjexplore.eval.experiments import EXPERIMENTS, TEAM_EXPERIMENTS
    from mjexplore.eval.summaries import team_runs

    teams = set(team_runs(sweep).values())
    if not teams:
        return  # No finished runs: collect says so.
    wanted = experiment in TEAM_EXPERIMENTS
    if teams != {wanted}:
        kind = "a team sweep (bench --robots)" if True in teams else "a single-robot sweep"
        if teams == {True, False}:
            kind = "a folder of team and single-robot sweeps"
        fits = TEAM_EXPERIMENTS if True in teams else \
            [e.name for e in EXPERIMENTS if e.name not in TEAM_EXPERIMENTS]
        raise UserInputError(f"{str(sweep)!r} is {kind}, and --experiment {experiment} takes "
                             f"{'team' if wanted else 'single-robot'} sweeps: collect it as "
                             f"one of {', '.join(fits)}" + (", each kind from its own --out "
                             "folder." if len(teams) == 2 else "."))


def cmd_collect_training(args: argparse.Namespace) -> int:
    from mjexplore.eval.training_record import collect_training

    if not args.run.is_dir():
        raise UserInputError(f"{str(args.run)!r} is not a folder: give a run folder of "
                             "'mjexplore train --out'.")
    check_output_folder(args.data, "--data")
    record = collect_training(args.run, args.data, args.name)
    print(json.dumps({"record": str(record),
                      "files": sorted(p.name for p in record.iterdir())}))
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from mjexplore.eval.report import build_report

    if not args.data.is_dir():
        raise UserInputError(f"{str(args.data)!r} is not a folder of sweep summaries: make them "
                             "with 'mjexplore collect SWEEP --experiment NAME'.")
    if args.out.suffix.lower() != ".md" or args.out.is_dir():
        raise UserInputError(f"--out {str(args.out)!r}: give the report a Markdown file name "
                             "ending in .md (e.g. docs/results.md).")
    check_output_folder(args.out.parent, "--out's folder")
    check_output_folder(args.figures if args.figures is not None else args.out.with_suffix(""),
                        "--figures")
    print(build_report(args.data, args.out, args.figures))
    return 0


def _add_episode_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="sim", choices=["sim", "real"],
                   help="motion profile: sim (0.5 m/s, 6 m lidar) or real (0.18 m/s, 5 m)")
    p.add_argument("--lidar-range", type=_positive, default=None,
                   help="lidar range in metres (default: the profile's, lds01's 3.5 with "
                        "--lidar-model lds01; Explore-Bench uses 7)")
    p.add_argument("--max-time", type=_positive, default=1800.0,
                   help="time cap in simulated seconds")
    p.add_argument("--target-ratio", type=float, default=0.985,
                   help="exploration ratio that ends the episode")
    p.add_argument("--localization", default="ground_truth",
                   choices=["ground_truth", "odometry", "scan_matching"],
                   help="where the robot believes it is, for everything it does (mapping, "
                        "navigation, goals): the true pose, wheel odometry, or odometry "
                        "corrected by matching each scan against the map; metrics.json gets "
                        "pose_error_rmse_m, pose_error_max_m and pose_error_aligned_rmse_m "
                        "(after the rigid alignment that fits the estimate best: the map's "
                        "distortion without its frame's offset)")
    p.add_argument("--odometry-error", default="none", choices=["none", "typical"],
                   help="none (the model's exact wheel geometry) or typical (per-seed wheel "
                        "radius and track width errors, wheel slip, and with "
                        "--odometry-heading imu the gyro's scale, bias and noise; see "
                        "sim/odometry.py)")
    p.add_argument("--odometry-heading", default="wheels", choices=["wheels", "imu"],
                   help="where the odometry's heading comes from: the wheels, or the IMU's "
                        "gyro as on the real Turtlebot3 (turtlebot3_node's use_imu); the "
                        "scan_matching localiser then estimates the gyro's bias")
    p.add_argument("--lidar-noise", type=float, default=None,
                   help="the ideal lidar's Gaussian range noise std in metres "
                   "(default: 0.01)")
    p.add_argument("--people", type=_whole("", 0), default=0, metavar="N",
                   help="N pedestrians walking between random goals (the social force "
                        "model, sim/people.py), seen by the lidar and touched by the robot "
                        "(default: nobody)")
    p.add_argument("--people-density", type=_positive, default=None, metavar="D",
                   help="instead of --people: D pedestrians per 100 m^2 of the floor a "
                        "person can walk, the count set per scene (e.g. 2: an office "
                        "corridor at a quiet hour) (default: none)")
    _add_lidar_model_arg(p)


def _add_lidar_model_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lidar-model", default="ideal", choices=["ideal", "lds01"],
                   help="ideal (every beam at once, constant noise; the paper's tables) or "
                        "lds01 (the Turtlebot3's LDS-01: 5 Hz, 0.12-3.5 m, range-dependent "
                        "noise, dropouts, motion skew)")


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line that points at ``--help`` (argparse
    prints its usage block first)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {_one_line(message)} (see {self.prog} --help)\n")

    def _get_values(self, action: argparse.Action, arg_strings: list[str]):
        # Python 3.11's argparse drops the value of ``--max-time=--`` as if it were the
        # '--' separator and stores an empty list, which no check expects.
        if action.option_strings and action.nargs in (None, "?") and arg_strings == ["--"]:
            self.error(f"argument {'/'.join(action.option_strings)}: expected a value, not "
                       "'--'")
        return super()._get_values(action, arg_strings)


def build_parser() -> argparse.ArgumentParser:
    from mjexplore.eval.methods import METHODS

    parser = _Parser(
        prog="mjexplore",
        description="MuJoCo simulator and learning stack for lidar-based exploration.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    gen = sub.add_parser(
        "scene-gen", help="generate a scene (MJCF + ground-truth map + preview)",
        description="Generate a seeded scene of a family, or import a map_server map, an "
                    "image or a 3D building model, and write scene.xml, map.yaml/.pgm, "
                    "preview.png and scene.json (--export: also as a mesh file).")
    gen.add_argument("family", nargs="?", help="office, maze, loop, corridor, rooms, hall, "
                     "labmaze, or several joined by '+' (e.g. loop+rooms)")
    gen.add_argument("--seed", type=_seed, default=0, help="generator seed")
    gen.add_argument("--size", type=_size, default=None,
                     help="WIDTHxHEIGHT in metres, outer walls included (default "
                     f"{DEFAULT_SCENE_SIZE[0]:g}x{DEFAULT_SCENE_SIZE[1]:g})")
    gen.add_argument("--wall-thickness", type=_positive, default=None,
                     help="metres (default 0.15)")
    gen.add_argument("--resolution", type=_positive, default=None,
                     help="ground-truth cell size in metres (default: 0.05); for --from-map "
                     "IMAGE, the image's metres per pixel (no default: give it)")
    gen.add_argument("--from-map", metavar="MAP", help="map_server YAML, or an image with "
                     "--resolution (bright pixels free) (default: none, a generated scene)")
    gen.add_argument("--from-mesh", metavar="FILE", help="3D building model (GLB, glTF, OBJ, "
                     "STL, PLY, OFF), cut at the lidar's height (default: none)")
    gen.add_argument("--mesh-units", default=None, metavar="UNIT",
                     help="--from-mesh file's unit: m (default), cm, mm, in or ft")
    gen.add_argument("--mesh-scale", type=_positive, default=None, metavar="S",
                     help="--from-mesh file's metres per unit, instead of --mesh-units "
                     "(default: that of --mesh-units)")
    gen.add_argument("--up-axis", choices=["y", "z"], default=None,
                     help="--from-mesh file's up axis (default: y for GLB, glTF and OBJ; z for "
                     "STL, PLY and OFF)")
    gen.add_argument("--floor-z", type=float, default=None, metavar="Z",
                     help="--from-mesh floor height in metres, z up (default: found; give it "
                     "to pick a storey)")
    gen.add_argument("--height", type=_positive, default=None, metavar="H",
                     help="--from-mesh cut height above the floor in metres (default: the "
                     "lidar's, 0.132)")
    gen.add_argument("--start", type=_pose, default=None, metavar="X,Y[,YAW]",
                     help="start pose for --from-map and --from-mesh, metres and radians in "
                     "the map frame (default: a free cell picked from the seed)")
    gen.add_argument("--name", default=None, help="scene name (default from family and size)")
    gen.add_argument("--out", type=Path, default=None,
                     help="output folder (no default: needed unless --list or "
                     "--from-scene)")
    gen.add_argument("--export", type=Path, default=None, metavar="FILE",
                     help="also write the scene's walls and floor as a mesh (.glb y-up for "
                     "Foxglove, Blender, Gazebo; .obj, .stl, .ply) in an existing folder "
                     "(default: no mesh)")
    gen.add_argument("--from-scene", metavar="SCENE", help="with --export: write an existing "
                     "scene (canonical name, folder or MJCF) as a mesh, nothing else "
                     "(default: none)")
    gen.add_argument("--list", action="store_true", help="list families and canonical scenes")
    gen.set_defaults(func=cmd_scene_gen)

    drive = sub.add_parser(
        "drive", help="drive the robot through a scene with a reactive controller",
        description="Drive the robot in closed loop (wandering toward open space) and write "
                    "kinematics.csv, trajectory.png, summary.json and config.json.")
    drive.add_argument("--scene", default="office",
                       help="canonical scene name, scene folder, MJCF or map_server YAML")
    drive.add_argument("--duration", type=_positive, default=120.0,
                       help="simulated seconds to drive")
    drive.add_argument("--profile", default="sim", choices=["sim", "real"],
                       help="motion profile: sim (0.5 m/s) or real (0.18 m/s)")
    drive.add_argument("--lidar-range", type=_positive, default=None,
                       help="lidar range in metres (default: the profile's, lds01's 3.5 "
                            "with --lidar-model lds01)")
    drive.add_argument("--lidar-noise", type=float, default=None,
                       help="the ideal lidar's Gaussian range noise std in metres "
                       "(default: 0)")
    _add_lidar_model_arg(drive)
    drive.add_argument("--seed", type=_seed, default=0, help="seed of the drive")
    drive.add_argument("--out", type=Path, required=True, help="run folder")
    drive.set_defaults(func=cmd_drive)

    explore = sub.add_parser(
        "explore", help="run one exploration episode and write its run folder",
        description="Explore a scene with one explorer in full physics until the exploration "
                    "ratio reaches the target, the robot lingers, or time runs out. Writes "
                    "metrics.json, config.json, ratio.csv, kinematics.csv, plots and an MCAP. "
                    "Unless told otherwise it explores the office scene (40 x 25 m) with the "
                    "nearest-frontier explorer, seed 0, for at most 1800 simulated seconds.")
    explore.add_argument("--scene", default="office",
                         help="canonical scene name, scene folder, MJCF or map_server YAML")
    explore.add_argument("--explorer", default="nearest", metavar="METHOD",
                         help="one of: " + "; ".join(f"{k}: {v}" for k, v in METHODS.items())
                         + " (default: %(default)s)")
    explore.add_argument("--policy", default=None, metavar="NAME|PATH",
                         help="the policy a learned explorer (gvn, cnn) runs: a shipped "
                         "model's name ('mjexplore policies' lists them) or a weights file "
                         "or run folder of your own (default: the recommended model)")
    explore.add_argument("--no-masking", action="store_true",
                         help="run a learned GVN without invalid action masking (any TER "
                         "node may be chosen; the paper's 'masking removed' ablation)")
    explore.add_argument("--seed", type=_seed, default=0,
                         help="episode seed (start jitter, noise, odometry errors)")
    explore.add_argument("--out", type=Path, required=True, help="run folder")
    explore.add_argument("--no-mcap", action="store_true", help="do not write episode.mcap")
    explore.add_argument("--mcap-profile", default=None, choices=["foxglove", "ros2"],
                         help="messages in episode.mcap: foxglove (Foxglove schemas, the "
                         "default) or ros2 (ROS 2 messages, CDR: for ros2 bag play)")
    explore.add_argument("--live", type=_port, nargs="?", const=8765, default=None,
                         metavar="PORT", help="serve the episode's topics to Foxglove while it "
                         "runs (Open connection, ws://127.0.0.1:PORT; PORT 8765 if not given) "
                         "(default: no live server)")
    explore.add_argument("--live-host", default=None, metavar="ADDRESS",
                         help="address the live server binds (127.0.0.1: this machine only; "
                         "0.0.0.0: every interface) (default: 127.0.0.1)")
    explore.add_argument("--live-rate", type=_positive, default=None, metavar="R",
                         help="pace the live episode at R simulated seconds per second (1: "
                         "real time; default: as fast as it runs)")
    explore.add_argument("--live-wait", action="store_true",
                         help="start the episode only once Foxglove subscribes to a topic")
    explore.add_argument("--no-progress", action="store_true",
                         help="no progress bar (it is shown only when stderr is a terminal)")
    explore.add_argument("--video", default=None, metavar="PATH",
                         help="also film the episode (3D view beside the map panel) into "
                         "an H.264 MP4 at PATH, a .mp4 file in an existing folder, --out's "
                         "folder or beside it (and OUT/video.mp4) (default: no video)")
    explore.add_argument("--robots", type=_count, default=1, metavar="N",
                         help="explore with a team of N robots in one world and one shared "
                         "map; --explorer then takes a team method (assign_greedy, "
                         "assign_optimal, mmpf) or any single-robot one, run by every robot "
                         "on its own (the naive team) (default: 1)")
    explore.add_argument("--starts", default=None, metavar="X,Y,YAW;...|close|far|drawn",
                         help="the team's start poses, one per robot separated by ';' "
                         "(metres, radians, map frame), Explore-Bench's 'close' or 'far' "
                         "placement on its own maps (2 robots), or 'drawn' (default: drawn, "
                         "robot 0 at the scene's start, the others drawn 1-3 m around it "
                         "from the seed; --robots is bounded by the room there)")
    explore.add_argument("--unknown-starts", action="store_true",
                         help="with --robots: the robots do not know their relative start "
                         "poses; each maps in its own frame until its map is merged into the "
                         "team's by matching (the merge error against the truth is in "
                         "metrics.json) (default: known starts, one shared map)")
    _add_video_args(explore)
    _add_episode_args(explore)
    explore.set_defaults(func=cmd_explore)

    pol = sub.add_parser(
        "policies", help="list the shipped policies (models/) the learned explorers can run",
        description="List the models under models/: name, kind (the explorer that runs "
                    "it), the masking it was trained with, and its model card's summary.")
    pol.set_defaults(func=cmd_policies)

    ex = sub.add_parser(
        "export-policy", help="a training checkpoint's policy as weights, or a policy's actor "
        "as ONNX",
        description="Export the policy of a training checkpoint (.pt) as a weights file "
                    "(.safetensors) the learned explorers run, or with --onnx the actor of a "
                    "weights file as an ONNX model: the decision's observation arrays (flat, "
                    "batch first, in the order of its observation_keys metadata) and the "
                    "boolean action_mask in, the masked action logits and the greedy action "
                    "out (docs/guide/deployment.md). Prints one JSON line.")
    ex.add_argument("source", help="training checkpoint (.pt), or with --onnx a policy "
                    "weights file (.safetensors)")
    ex.add_argument("out", help="weights file to write (.safetensors), or with --onnx the "
                    "model (.onnx)")
    ex.add_argument("--onnx", action="store_true",
                    help="export the actor of a weights file as an ONNX model")
    ex.add_argument("--git-revision", default=None,
                    help="the revision the run was started from, if the checkpoint records "
                    "another (default: the checkpoint's own)")
    ex.set_defaults(func=cmd_export_policy)

    pt = sub.add_parser(
        "plot-training", help="a training run's curves against its prior and the oracle",
        description="Draw a run folder's learning curve (mean validation exploration time "
                    "against decisions trained, with pocket_nearest, nearest and the oracle "
                    "measured on the same layouts as lines, cached in RUN/baselines.json), "
                    "its per-layout evaluations and episode return and length into OUT.png, "
                    "and print the run's record as one JSON line (docs/guide/training.md).")
    pt.add_argument("run", type=Path, help="a run folder of mjexplore train --out")
    pt.add_argument("out", type=Path, help="the PNG to write")
    pt.add_argument("--workers", type=_count, default=2,
                    help="processes measuring the baselines (default: %(default)s)")
    baselines = pt.add_mutually_exclusive_group()
    baselines.add_argument("--recompute-baselines", action="store_true",
                           help="measure the baselines again even if RUN/baselines.json has "
                           "them")
    baselines.add_argument("--no-baselines", action="store_true",
                           help="neither measure nor show the baselines")
    pt.add_argument("--departures", action="store_true",
                    help="run the shipped policy's greedy episodes on the validation layouts "
                    "and count its departures from its prior (kept in RUN/departures.json)")
    pt.add_argument("--weights", type=Path, default=None,
                    help="the policy for --departures (default: RUN/best.safetensors, else "
                    "RUN/policy.safetensors)")
    pt.set_defaults(func=cmd_plot_training)

    from mjexplore.eval.probe import DEFAULT_MODES, MODES  # Light: the episodes load lazily.

    pp = sub.add_parser(
        "probe-policy", help="a trained policy against random and greedy choices, same layouts",
        description="Run whole episodes of a config's training env with each mode choosing "
                    "every action: the trained policy (its most probable valid action), a "
                    "uniformly random valid action, the greedy valid action nearest the robot "
                    "and a residual policy's prior alone (prior), on the same layouts and "
                    "start poses; with --heldout or --unseen a classic explorer's name is a "
                    "mode too, driving the same episode on its own. Prints one JSON line: per "
                    "mode the mean return, exploration time (s), path length (m) and episodes "
                    "explored, and learned_fraction, where the policy's mean return lies "
                    "between random (0) and greedy (1) (docs/guide/training.md).")
    pp.add_argument("--weights", required=True, help="exported policy (.safetensors)")
    pp.add_argument("--config", default=None,
                    help="training YAML whose env is used (default: the config stored with "
                    "the weights)")
    pp.add_argument("--episodes", type=_count, default=10, metavar="N",
                    help="episodes, on seeds --seed-base on (without --heldout or --unseen)")
    pp.add_argument("--seed-base", type=_seed, default=10_000, metavar="SEED",
                    help="the first episode's seed")
    pp.add_argument("--heldout", action="store_true",
                    help="the config's model-selection layouts instead of --episodes")
    pp.add_argument("--unseen", type=_whole("", 0), default=0, metavar="N",
                    help="this many generated layouts past the model-selection ones instead "
                    "of --episodes")
    pp.add_argument("--modes", default=",".join(DEFAULT_MODES),
                    help=f"comma-separated, of {', '.join(MODES)} and, with --heldout or "
                    "--unseen, explorer names (nearest, oracle, ...)")
    pp.add_argument("--workers", type=_count, default=2,
                    help="processes running the episodes")
    pp.set_defaults(func=cmd_probe_policy)

    n_scenes, n_explorers = len(BENCH_SCENES.split(",")), len(BENCH_EXPLORERS.split(","))
    bench = sub.add_parser(
        "bench", help="sweep scenes x explorers x seeds; tables and plots",
        description="Run every combination of scene, explorer and seed in worker processes "
                    "(resuming finished ones) and write results.md/.csv and the ratio and "
                    f"kinematics plots per scene. By default {n_scenes} scenes x {n_explorers} "
                    f"explorers x {BENCH_SEEDS} seeds: {n_scenes * n_explorers * BENCH_SEEDS} "
                    "full-physics episodes of up to 1800 simulated seconds each.")
    bench.add_argument("--scenes", default=BENCH_SCENES,
                       help="comma-separated scene names or paths (MJCF or map_server YAML) "
                       "(default: %(default)s)")
    bench.add_argument("--explorers", default=BENCH_EXPLORERS,
                       help="comma-separated methods (see explore --explorer), METHOD:POLICY "
                       "for a learned one with another model (':unmasked' appended runs it "
                       "without the mask), or a model's run label such as gvn_v3_naive "
                       "(default: %(default)s)")
    bench.add_argument("--seeds", type=int, default=BENCH_SEEDS,
                       help="seeds 0..N-1 per scene and explorer")
    bench.add_argument("--workers", type=int, default=2,
                       help="worker processes, one episode each at a time (with --ray alone: "
                       "the local Ray instance's CPUs)")
    _add_ray_argument(bench, "run each episode as a Ray task (one CPU each; the scene and "
                      "weights travel with it, the run folder comes back)", "no Ray, --workers "
                      "processes")
    bench.add_argument("--out", type=Path, required=True, help="sweep folder")
    bench.add_argument("--mcap", nargs="?", const="foxglove", default=None,
                       choices=["foxglove", "ros2"], metavar="PROFILE",
                       help="also write an MCAP per episode; PROFILE foxglove (the default "
                       "when PROFILE is not given) or ros2 as explore's --mcap-profile "
                       "(default: no MCAPs)")
    bench.add_argument("--no-progress", action="store_true",
                       help="no progress bar on a terminal, no progress lines elsewhere")
    bench.add_argument("--robots", type=_count, default=1, metavar="N",
                       help="sweep team episodes of N robots (team methods or single-robot "
                       "ones as naive teams; default methods "
                       f"{TEAM_BENCH_METHODS}), each scene also run by one robot with "
                       "nearest for the time beside (default: 1, single-robot sweeps)")
    bench.add_argument("--starts", default=None, metavar="PLACEMENTS",
                       help="with --robots: comma-separated start placements, 'close' and "
                       "'far' (Explore-Bench's, on its own maps) or 'drawn' (robot 0 at the "
                       "scene's start, the others drawn 1-3 m around it) (default: drawn)")
    bench.add_argument("--unknown-starts", action="store_true",
                       help="with --robots: unknown relative start poses, maps merged by "
                       "matching (see explore --unknown-starts) (default: known starts)")
    _add_episode_args(bench)
    bench.set_defaults(func=cmd_bench)

    ren = sub.add_parser(
        "render", help="re-render a recorded run (its episode.mcap) as a video",
        description="Rebuild the frames of a run folder written by 'mjexplore explore' from its "
                    "episode.mcap (3D view beside the map panel) into an H.264 MP4.")
    ren.add_argument("run_dir", type=Path, help="run folder")
    ren.add_argument("--out", type=Path, default=None,
                     help="video path, a .mp4 file in an existing folder (default: "
                     "RUN_DIR/video.mp4)")
    ren.add_argument("--no-progress", action="store_true",
                     help="no progress bar on a terminal, no progress lines elsewhere")
    _add_video_args(ren)
    ren.set_defaults(func=cmd_render)

    tr = sub.add_parser(
        "train", help="train a policy with MaskablePPO (checkpoints, resume, TensorBoard)",
        description="Train the policy a YAML config describes (see training/gvn.yaml) into a "
                    "run folder: config.yaml, checkpoints/, tb/ (TensorBoard: losses, KL, "
                    "entropy, explained variance, evaluations) and the final "
                    "policy.safetensors; from the first held-out evaluation on (every "
                    "eval.every steps of the config; none in a shorter run) also eval.csv and "
                    "best.safetensors. --resume continues an interrupted run.")
    tr.add_argument("--config", type=Path, required=True, help="training YAML")
    tr.add_argument("--out", type=Path, required=True, help="run folder")
    tr.add_argument("--resume", action="store_true",
                    help="continue the run in --out from its last checkpoint")
    tr.add_argument("--total-steps", type=_count, default=None, metavar="N",
                    help="decision steps to train for, all envs together, rounded up to "
                         "whole rollouts of ppo.n_steps x n_envs (default: the config's "
                         "total_steps)")
    tr.add_argument("--n-envs", type=_count, default=None, metavar="N",
                    help="environments, one worker process each; may change on --resume "
                         "(default: the config's n_envs)")
    tr.add_argument("--seed", type=_seed, default=None, metavar="N",
                    help="the training seed (network initialisation, the layouts drawn, PPO's "
                         "sampling): another training seed of the same recipe, judged on the "
                         "same validation layouts (eval.seed stays); not on --resume "
                         "(default: the config's seed)")
    _add_ray_argument(tr, "run each env in a Ray actor", "no Ray, worker processes on this "
                      "machine", "; may change on --resume")
    tr.add_argument("--device", default="auto", metavar="DEVICE",
                    help="the learner's torch device: auto (a GPU when there is one), cpu, "
                         "cuda, cuda:1 ... (default: auto); may change on --resume")
    tr.add_argument("--init-weights", type=Path, default=None, metavar="WEIGHTS",
                    help="start a fresh run from these weights (of the config's network, e.g. "
                    "a warm start saved by python -m tools.research.dagger_probe) instead of "
                    "the config's imitation warm start (default: none, the config's own)")
    tr.add_argument("--no-progress", action="store_true",
                    help="no progress bar on a terminal, no progress lines elsewhere")
    tr.set_defaults(func=cmd_train)

    im = sub.add_parser(
        "imitate", help="DAgger on the ground-truth oracle, round by round into a run folder "
                        "(resumable)",
        description="Run the imitation settings of a training YAML (imitation: the expert's "
                    "episodes, then DAgger rounds of the learner's own, every decision "
                    "labelled by the oracle) into a run folder: config.yaml, rounds/ (each "
                    "round's labelled decisions), imitation.json (each round's figures) and "
                    "policy.safetensors (the weights after the last round; start PPO from it "
                    "with `mjexplore train --init-weights`). --resume continues after the "
                    "last finished round.")
    im.add_argument("--config", type=Path, required=True,
                    help="training YAML with an imitation section (e.g. "
                         "training/gvn_dagger_lookahead.yaml)")
    im.add_argument("--out", type=Path, required=True, help="run folder")
    im.add_argument("--resume", action="store_true",
                    help="continue the run in --out after its last finished round")
    im.add_argument("--rounds", type=_count, default=None, metavar="N",
                    help="rounds in all, the expert's first (default: the config's "
                         "1 + imitation.dagger_iterations); may grow on --resume")
    im.add_argument("--seed", type=_seed, default=None, metavar="N",
                    help="the run's seed (network initialisation, refits' order; the "
                         "episodes' layouts follow imitation.seed) (default: the config's "
                         "seed)")
    im.set_defaults(func=cmd_imitate)

    tp = sub.add_parser(
        "train-pockets", help="train the frontier-pocket predictor the v3 GVN reads",
        description="Collect map patches of frontiers and their true pockets on generated "
                    "layouts, fit the predictor (see training/pockets.yaml) and write "
                    "pockets.safetensors and fit.json into --out.")
    tp.add_argument("--config", type=Path, required=True, help="pocket-training YAML")
    tp.add_argument("--out", type=Path, required=True, help="output folder")
    tp.add_argument("--workers", type=_count, default=2, help="collection processes")
    tp.add_argument("--episodes", type=_count, default=None, metavar="N",
                    help="collection episodes (default: the config's episodes)")
    tp.add_argument("--no-progress", action="store_true",
                    help="no progress bar on a terminal, no progress lines elsewhere")
    tp.set_defaults(func=cmd_train_pockets)

    tr = sub.add_parser(
        "train-predictor", help="train the map predictor (the unseen map from the partial one)",
        description="Record partial maps at the decisions of episodes on generated layouts, "
                    "fit the map predictor to their ground truth (see training/predictor.yaml) "
                    "and write the model folder --out: predictor.safetensors, README.md (its "
                    "card, with its quality beside inpainting and unknown-as-free/occupied), "
                    "quality.json, config.yaml. Run it again with the same --out to resume.")
    tr.add_argument("--config", type=Path, required=True, help="predictor-training YAML")
    tr.add_argument("--out", type=Path, required=True, help="model folder")
    tr.add_argument("--workers", type=_count, default=2,
                    help="collection processes (with --ray alone: the local Ray instance's "
                    "CPUs)")
    _add_ray_argument(tr, "record each collection episode as a Ray task (its shard comes back "
                      "as data)", "no Ray, --workers processes")
    tr.add_argument("--episodes", type=_count, default=None, metavar="N",
                    help="collection episodes (default: the config's)")
    tr.add_argument("--epochs", type=_count, default=None, metavar="N",
                    help="passes over the training maps (default: the config's)")
    tr.add_argument("--no-progress", action="store_true",
                    help="no progress bar on a terminal, no progress lines elsewhere")
    tr.set_defaults(func=cmd_train_predictor)

    co = sub.add_parser(
        "collect", help="summarise a bench sweep for the results report",
        description="Keep what the report needs from a sweep's run folders (metrics, ratio "
                    "curves every 2 s, kinematic statistics) in DATA/EXPERIMENT.json, small "
                    "enough to commit. Experiments the report knows: table1, gvn_v2, gvn_v3, "
                    "ablation, ablation_v2, ablation_v3, lobby_real, realistic, realistic_truth, "
                    "realistic_odometry, realistic_imu, explore_bench, ladder, ariadne, teams, "
                    "teams_explore_bench, people, people_5, people_10, people_20. teams and "
                    "teams_explore_bench summarise team sweeps (bench --robots); people_N the "
                    "people benchmark's sweep among N people (bench --people N).")
    co.add_argument("sweep", type=Path, help="the sweep's --out folder")
    co.add_argument("--experiment", required=True, help="summary name (e.g. table1)")
    co.add_argument("--data", type=Path, default=Path("docs/results/data"),
                    help="summaries folder")
    co.add_argument("--command", dest="sweep_command", default=None,
                    help="the sweep's command (default: the one recorded in sweep.json)")
    co.add_argument("--kinematics", action="store_true",
                    help="also keep velocity and acceleration over time (Fig. 9)")
    co.add_argument("--reference", type=Path, default=None,
                    help="JSON-lines reference results to keep (ARiADNE's greedy_reference) "
                    "(default: none)")
    co.add_argument("--stills", default=None, metavar="METHOD",
                    help="copy METHOD's seed-0 ter.png per scene into --figures (default: "
                    "none)")
    co.add_argument("--figures", type=Path, default=Path("docs/results"),
                    help="report figures folder, for --stills")
    co.add_argument("--strict", action="store_true",
                    help="exit 1 when any episode is left out (failed, cut off by Ctrl-C, not "
                    "run yet, or metrics outside a run folder); each is listed on stderr "
                    "either way")
    co.add_argument("--merge", action="store_true",
                    help="keep the existing summary's runs of the scene and method pairs this "
                    "sweep lacks")
    co.set_defaults(func=cmd_collect)

    ct = sub.add_parser(
        "collect-training", help="keep a training run's record for the results report",
        description="Keep what the report needs of a training run (its validation "
                    "evaluations, the baselines mjexplore plot-training measured on the same "
                    "layouts, the resolved config, decisions trained and the sessions' hosts, "
                    "cores and wall time; no weights) in DATA/training/NAME/, for the "
                    "report's learning curve. Collect again as the run goes on.")
    ct.add_argument("run", type=Path, help="the run folder (mjexplore train --out)")
    ct.add_argument("--name", default=None,
                    help="the record's name (default: the run folder's name)")
    ct.add_argument("--data", type=Path, default=Path("docs/results/data"),
                    help="summaries folder")
    ct.set_defaults(func=cmd_collect_training)

    rep = sub.add_parser(
        "report", help="write docs/results.md from the collected sweep summaries",
        description="Regenerate the results report (the paper's tables and figures) from the "
                    "summaries in --data; runs nothing.")
    rep.add_argument("--data", type=Path, default=Path("docs/results/data"),
                     help="summaries folder")
    rep.add_argument("--out", type=Path, default=Path("docs/results.md"),
                     help="report file (Markdown)")
    rep.add_argument("--figures", type=Path, default=None,
                     help="figures folder (default: beside --out, named as it without "
                     "the suffix: docs/results for docs/results.md)")
    rep.set_defaults(func=cmd_report)
    for command in sub.choices.values():
        command.formatter_class = _HelpFormatter
    return parser


# The MUJOCO_GL values MuJoCo accepts on Linux (it refuses others when it is imported).
MUJOCO_GL_VALUES = ("egl", "osmesa", "glx", "glfw", "", "disable", "disabled", "off", "false",
                    "0", "enable", "enabled", "on", "true", "1")


def _check_gl_setting() -> None:
    value = os.environ.get("MUJOCO_GL")
    if (sys.platform.startswith("linux") and value is not None
            and value.lower().strip() not in MUJOCO_GL_VALUES):
        raise UserInputError(f"MUJOCO_GL={value!r} is not a GL backend MuJoCo knows: set it "
                             "to egl or osmesa, or unset it to let mjexplore choose.")


def _one_line(text: str) -> str:
    """``text`` on one line (a message that quotes a multi-line cause)."""
    return " ".join(text.split())


def _os_error_message(exc: OSError) -> str:
    """One line for an operating-system error: the path, what went wrong and the fix."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    paths = [str(f) for f in (exc.filename, exc.filename2) if f is not None]
    if not paths:
        return (f"{reason} ({type(exc).__name__}): check the paths given (a file in the way, "
                "permissions, a read-only or virtual filesystem, a full disk) and run again; "
                "-v shows where it happened.")
    return (f"cannot use {' or '.join(repr(p) for p in paths)}: {reason}: check that path (a "
            "file in the way, permissions, a read-only or virtual filesystem, a full disk) or "
            "choose another, and run again.")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.command_line = shlex.join(["mjexplore"] + argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    from mjexplore.episode.workers import bound_heap_growth

    bound_heap_growth()  # Long runs on large maps: see mjexplore/episode/workers.py.
    try:
        _check_gl_setting()
        return args.func(args)
    except UserInputError as exc:
        print(f"mjexplore {args.command}: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except OSError as exc:
        log.debug("the error's traceback", exc_info=True)
        print(f"mjexplore {args.command}: error: {_one_line(_os_error_message(exc))}",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mjexplore {args.command}: interrupted; finished outputs are kept (an "
              "interrupted episode's run folder is complete, with end_reason 'interrupted').",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
