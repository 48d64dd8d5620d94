"""The ``explore`` job: one episode, of one robot or a team, written to a run folder.

Run folder: ``metrics.json`` (the paper's metrics), ``config.json`` (resolved settings and
git revision), ``ratio.csv`` (exploration ratio over simulated time), ``kinematics.csv``,
``ratio.png``, ``kinematics.png``, ``map.png`` (final map and trajectory), ``ter.png`` (the
final map and TER) and ``episode.mcap``. A team's run (N > 1 robots) has the team's
metrics (``per_robot`` among them), ratio and map, and per robot ``robot_I/kinematics.csv``
and ``robot_I/coverage.csv`` (its own scans' exploration ratio over time) in place of
``kinematics.csv``; its MCAP has the topics of each robot under ``/robot_I``. The folder
appears complete or not at all.

Ctrl-C (SIGINT, main thread) during :func:`write_run`: before the episode starts it stops the
job at once, with nothing written; from then on the first one only ends the episode
(:meth:`~mjexplore.episode.Episode.run`) and the outputs of the run so far are finished, then
:class:`RunInterrupted` says what was kept. A second Ctrl-C stops at once (the atomic writes
leave nothing half-written).
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mjexplore.episode import Episode, EpisodeConfig, Interrupted
from mjexplore.episode.engine import SigintFlag
from mjexplore.episode.team import TeamConfig
from mjexplore.errors import UserInputError
from mjexplore.eval.methods import make_explorer, team_explorers
from mjexplore.eval.plots import kinematics_figure, map_figure, ratio_figure, team_ratio_figure
from mjexplore.eval.progress import EpisodeProgress
from mjexplore.io.atomic import atomic_directory, write_bytes_atomic, write_text_atomic
from mjexplore.io.mcap_log import FoxgloveEpisodeLog
from mjexplore.io.provenance import git_revision
from mjexplore.policies.models import MODELS_DIR, WEIGHTS_NAME, shipped_models
from mjexplore.scenes.scene import SceneFiles


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`write_run`, raised once the outputs that could be were finished.

    Attributes:
        metrics: The run's metrics (``end_reason`` 'interrupted' if the episode was cut
            short), or None if the episode had not started or its outputs were not finished.
        kept: The outputs finished and in place: the run folder, then the video at the
            path asked for; empty if nothing was kept.
    """

    def __init__(self, metrics: dict[str, Any] | None, kept: list[Path]) -> None:
        super().__init__("run interrupted")
        self.metrics = metrics
        self.kept = kept


class _HeldSigint(SigintFlag):
    """Ctrl-C during a run: at once until :meth:`hold` (called when the episode starts),
    then the first one is only noted (``raised``) and a second one stops at once; while the
    episode runs, its own handler of the same kind takes over."""

    def __init__(self) -> None:
        super().__init__()
        self.holding = False

    def hold(self) -> None:
        self.holding = True

    def _handle(self, signum, frame) -> None:
        if not self.holding:
            raise KeyboardInterrupt
        super()._handle(signum, frame)


class Observers:
    """Fans an episode's observer hooks out to several observers (each may be None, and
    each has the hooks it needs: see :class:`~mjexplore.episode.engine.Episode`)."""

    def __init__(self, *observers: Any) -> None:
        self.observers = [o for o in observers if o is not None]

    def on_scan(self, agent, scan) -> None:
        for o in self.observers:
            if hasattr(o, "on_scan"):
                o.on_scan(agent, scan)

    def on_decision(self, agent, state) -> None:
        for o in self.observers:
            if hasattr(o, "on_decision"):
                o.on_decision(agent, state)

    def on_step(self, episode) -> None:
        for o in self.observers:
            if hasattr(o, "on_step"):
                o.on_step(episode)

    def close(self) -> None:
        """Closes every observer, even if one fails (files are left readable)."""
        errors = []
        for o in self.observers:
            try:
                o.close()
            except Exception as exc:  # noqa: BLE001 - re-raised below
                errors.append(exc)
        if errors:
            raise errors[0]


def _episode_logs(mcap_path: str | os.PathLike | None, mcap_profile: str,
                  live: Any, robots: int = 1) -> list[Any]:
    """The MCAP log in ``mcap_profile`` and the live stream (Foxglove messages); a team's
    MCAP has each robot's topics under its namespace."""
    if robots > 1:
        if mcap_profile == "ros2" or live is not None:
            raise UserInputError("a team's episode is logged with Foxglove messages to "
                                 "episode.mcap only: drop --mcap-profile ros2 and --live with "
                                 "--robots.")
        return [] if mcap_path is None else [FoxgloveEpisodeLog(mcap_path)]
    logs: list[Any] = []
    if mcap_profile == "ros2" and mcap_path is not None:
        from mjexplore.io.ros2_mcap import Ros2EpisodeLog

        logs.append(Ros2EpisodeLog(mcap_path))
        mcap_path = None
    if mcap_path is not None or live is not None:
        logs.append(FoxgloveEpisodeLog(mcap_path, live=live))
    return logs


def run_episode(scene: SceneFiles, explorer: str, seed: int, config: EpisodeConfig,
                mcap_path: str | os.PathLike | None = None,
                explorer_kwargs: dict | None = None, spec: str | None = None,
                video_path: str | os.PathLike | None = None,
                video: Any = None, stills_dir: str | os.PathLike | None = None,
                progress: bool = False, mcap_profile: str = "foxglove",
                live: Any = None, on_start: Callable[[], None] | None = None,
                robots: int = 1, starts: list | None = None,
                team_config: TeamConfig | None = None) -> Any:
    """Runs one episode, optionally logging it to MCAP (``mcap_profile``: ``foxglove`` or
    ``ros2`` messages), streaming it (``live``: a started
    :class:`~mjexplore.io.live.LiveServer`, which may hold the start until a client
    subscribes), filming it (``video_path`` with a
    :class:`~mjexplore.render.recorder.VideoConfig`), writing still figures and showing a
    progress bar on stderr (``progress``; drawn only when stderr is a terminal).
    ``on_start``: called with no arguments once the episode is built, as it starts.
    ``robots`` > 1: a team of that many robots, each running the method ``spec`` names (a
    team method's coordinated members, or the single-robot method alone each), from
    ``starts`` (None: drawn) with ``team_config``; a team's MCAP is Foxglove's, not live.

    Returns:
        The episode's :class:`~mjexplore.episode.EpisodeResult`, a team's
        :class:`~mjexplore.episode.metrics.TeamEpisodeResult`.
    """
    title = f"{scene.metadata.get('name', Path(scene.xml).parent.name)} / {explorer} / seed {seed}"
    if robots > 1:
        if explorer_kwargs:
            raise UserInputError("a team's explorers are built by their method's name alone.")
        title = title.replace(" / seed", f" / {robots} robots / seed")
    logs = _episode_logs(mcap_path, mcap_profile, live, robots)
    film = None
    if video_path is not None:
        from mjexplore.render.recorder import EpisodeVideo

        film = EpisodeVideo(video_path, video, title)
    observers = Observers(*logs, film, EpisodeProgress(config.max_time) if progress else None)
    interrupted = None
    try:
        if live is not None:
            live.wait_for_subscriber()  # Before the episode is built: it takes the first scan.
        built: Any = team_explorers(spec or explorer, robots)[0] if robots > 1 else \
            make_explorer(spec or explorer, **(explorer_kwargs or {}))
        episode = Episode(scene, built, seed, config, observer=observers, starts=starts,
                          team_config=team_config)
        if on_start is not None:
            on_start()
        result = episode.run()
    except Interrupted as exc:  # Stills of the run so far, then on up.
        interrupted, result = exc, exc.result
    finally:
        observers.close()  # Also on Ctrl-C: the MCAP and video are finished, readable files.
    recipe = getattr(episode.agents[0].explorer, "policy_recipe", None)  # A learned policy's.
    if recipe is not None:
        result.metrics["policy_recipe"] = recipe
    if stills_dir is not None:
        from mjexplore.render.recorder import write_stills

        write_stills(episode, stills_dir, title, render_3d=video_path is not None)
    if interrupted is not None:
        raise interrupted
    return result


def resolved_config(scene: SceneFiles, explorer: str, seed: int, config: EpisodeConfig,
                    explorer_kwargs: dict | None = None, spec: str | None = None,
                    metrics: dict[str, Any] | None = None,
                    command: str | None = None) -> dict[str, Any]:
    """A run's ``config.json``: the scene as given, the run label ``explorer`` and the method
    spec that built it, the seed, every episode setting, the revision, and for a learned
    explorer its policy (``name``: a shipped model or the weights file's path; ``file``;
    ``sha256``, the first 16 hex digits; ``recipe``), from the episode's ``metrics``; the
    ``command`` that made it (a sweep's; None for a run of ``explore``)."""
    policy = None
    if metrics is not None and "weights_sha256" in metrics:
        name = metrics["policy"]
        policy = {"name": name, "file": str(Path(MODELS_DIR.name, name, WEIGHTS_NAME))
                  if name in shipped_models() else name, "sha256": metrics["weights_sha256"],
                  "recipe": metrics.get("policy_recipe")}
    return {"scene": scene.source, "scene_metadata": scene.metadata, "explorer": explorer,
            "spec": spec or explorer, "policy": policy,
            "explorer_kwargs": explorer_kwargs or {}, "seed": seed,
            "episode": dataclasses.asdict(config), "git_revision": git_revision(),
            "command": command}


def write_run(out_dir: str | os.PathLike, scene: SceneFiles, explorer: str, seed: int,
              config: EpisodeConfig, mcap: bool | str = True,
              explorer_kwargs: dict | None = None, video: Any = None,
              progress: bool = False, live: Any = None, spec: str | None = None,
              video_path: str | os.PathLike | None = None,
              command: str | None = None, robots: int = 1, starts: list | None = None,
              team_config: TeamConfig | None = None) -> dict[str, Any]:
    """Runs an episode and writes its run folder atomically; returns the metrics.

    ``robots``, ``starts``, ``team_config``: a team, as :func:`run_episode` says.

    ``mcap``: a false value for no ``episode.mcap``, True or ``"foxglove"`` for one with
    Foxglove messages, ``"ros2"`` for ROS 2 ones. ``live`` as :func:`run_episode`.

    With ``video`` (a :class:`~mjexplore.render.recorder.VideoConfig`) the folder also gets
    ``video.mp4`` and the 3D still ``scene.png``; ``ter.png`` (final map, trajectory and TER)
    is always written. ``progress`` as :func:`run_episode`. ``explorer`` is the run's
    label; ``spec`` the method spec that builds the explorer, if not the label
    (:mod:`mjexplore.eval.methods`). ``video_path``: the video's path, if not (only) the
    folder's ``video.mp4``; copied there atomically once the folder is in place.
    ``command``: the command line that made the run (a sweep's), kept in ``config.json``.

    Raises:
        RunInterrupted: Ctrl-C (see the module docstring); it says what was kept.
    """
    out_dir = Path(out_dir)
    kept: list[Path] = []
    metrics = None
    try:
        sigint = _HeldSigint()
        with sigint:
            team = {"robots": robots, "starts": starts, "team_config": team_config}
            metrics = _write_run_folder(out_dir, scene, explorer, seed, config, mcap,
                                        explorer_kwargs, video, progress, live, spec, sigint,
                                        command, team)
            kept.append(out_dir)
            film = out_dir / "video.mp4"
            if video_path is not None and film.is_file():
                if Path(video_path).resolve() != film.resolve():
                    write_bytes_atomic(video_path, film.read_bytes())
                kept.append(Path(video_path))
    except KeyboardInterrupt:  # Before the episode, or a second Ctrl-C.
        raise RunInterrupted(metrics if kept else None, kept) from None
    if sigint.raised:  # During the episode (its end_reason says so) or after it.
        raise RunInterrupted(metrics, kept)
    return metrics


def _write_run_folder(out_dir: Path, scene: SceneFiles, explorer: str, seed: int,
                      config: EpisodeConfig, mcap: bool | str, explorer_kwargs: dict | None,
                      video: Any, progress: bool, live: Any, spec: str | None,
                      sigint: _HeldSigint, command: str | None,
                      team: dict[str, Any]) -> dict[str, Any]:
    """:func:`write_run`'s folder; holds Ctrl-C (``sigint``) from the episode's start."""
    robots = team["robots"]
    with atomic_directory(out_dir, "metrics.json") as tmp:
        try:
            result = run_episode(scene, explorer, seed, config,
                                 tmp / "episode.mcap" if mcap else None, explorer_kwargs,
                                 video_path=tmp / "video.mp4" if video is not None else None,
                                 video=video, stills_dir=tmp, progress=progress,
                                 mcap_profile=mcap if isinstance(mcap, str) else "foxglove",
                                 live=live, spec=spec, on_start=sigint.hold, **team)
        except Interrupted as exc:
            # Ctrl-C: the run so far becomes a complete folder (end_reason 'interrupted').
            sigint.raised, result = True, exc.result  # A second Ctrl-C stops at once.
        metrics = {"scene": scene.metadata.get("name", Path(scene.xml).parent.name),
                   "explorer": explorer, "seed": seed, **result.metrics}
        write_text_atomic(tmp / "metrics.json", json.dumps(metrics, indent=2) + "\n")
        resolved = resolved_config(scene, explorer, seed, config, explorer_kwargs, spec,
                                   metrics, command)
        if robots > 1:
            resolved.update({"robots": robots, "starts": [list(p) for p in result.starts],
                             "team": dataclasses.asdict(team["team_config"] or TeamConfig())})
        write_text_atomic(tmp / "config.json", json.dumps(resolved, indent=2, default=str) +
                          "\n")
        write_text_atomic(tmp / "ratio.csv", "t,exploration_ratio\n" + "".join(
            f"{t:.3f},{r:.6f}\n" for t, r in result.ratio_curve))
        title = f"{metrics['scene']} / {explorer} / seed {seed}"
        if robots > 1:
            for i, (log, curve) in enumerate(zip(result.kinematics, result.robot_curves)):
                folder = tmp / f"robot_{i}"
                folder.mkdir()
                write_text_atomic(folder / "kinematics.csv", log.to_csv())
                write_text_atomic(folder / "coverage.csv", "t,coverage\n" + "".join(
                    f"{t:.3f},{r:.6f}\n" for t, r in curve))
            title = title.replace(" / seed", f" / {robots} robots / seed")
            team_ratio_figure(result.ratio_curve, result.robot_curves, tmp / "ratio.png", title)
            map_figure(result.grid, [log.pose[:, :2] for log in result.kinematics],
                       result.goals, tmp / "map.png", title)
            return metrics
        write_text_atomic(tmp / "kinematics.csv", result.kinematics.to_csv())
        ratio_figure({explorer: [result.ratio_curve]}, tmp / "ratio.png", title)
        kinematics_figure({explorer: [result.kinematics]}, tmp / "kinematics.png", title)
        map_figure(result.grid, [result.kinematics.pose[:, :2]], [result.goals],
                   tmp / "map.png", title)
    return metrics


__all__ = ["RunInterrupted", "run_episode", "write_run"]
