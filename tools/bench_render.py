"""Offscreen rendering speed: frames per second at 640 x 480 (one core, this machine's GL).

Baseline in the same run: the same view (camera, trajectory) with MuJoCo's default
rendering settings (shadows, reflections, skybox, 4x multisampling) and opaque walls;
mjexplore's renderer turns those off and makes the walls translucent. Also the 2D map panel
and a whole video frame (3D view + panel) of an office episode. Prints one JSON line.

Usage: python tools/bench_render.py [--frames 60]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time

import mujoco

import mjexplore  # noqa: F401 - chooses MUJOCO_GL before mujoco loads


def _fps(fn, frames: int) -> float:
    fn()
    t = time.perf_counter()
    for _ in range(frames):
        fn()
    return frames / (time.perf_counter() - t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.render.recorder import EpisodeVideo, VideoConfig, episode_panel
    from mjexplore.render.scene_view import CameraConfig, SceneView
    from mjexplore.scenes.canonical import resolve_scene

    scene = resolve_scene("office")
    episode = Episode(scene, make_explorer("nearest"), 0, EpisodeConfig(max_time=60.0))
    episode.run()
    sim = episode.sim
    traj = sim.kinematics_rows[:, 5:7]

    base_model = mujoco.MjModel.from_xml_path(str(scene.xml))
    base_data = mujoco.MjData(base_model)
    base_data.qpos[:] = sim.data.qpos
    mujoco.mj_forward(base_model, base_data)
    default = SceneView(base_model, 640, 480, CameraConfig(wall_alpha=1.0), fast=False)

    def baseline() -> None:
        default.render(base_data, sim.pose, traj)

    view = SceneView(sim.model, 640, 480)
    scratch = tempfile.mkdtemp()
    film = EpisodeVideo(os.path.join(scratch, "bench.mp4"), VideoConfig())
    out = {
        "gl_backend": os.environ.get("MUJOCO_GL"),
        "baseline_default_settings_fps": round(_fps(baseline, args.frames), 1),
        "scene_view_fps_640x480": round(_fps(lambda: view.render(sim.data, sim.pose, traj),
                                             args.frames), 1),
        "map_panel_fps_640x480": round(_fps(lambda: episode_panel(episode, 640, 480),
                                            args.frames), 1),
        "video_frame_fps_1280x480": round(_fps(lambda: film.writer.append(film.frame(episode)),
                                               args.frames), 1),
    }
    film.writer.close()
    shutil.rmtree(scratch)
    out["speedup_vs_default_settings"] = round(
        out["scene_view_fps_640x480"] / out["baseline_default_settings_fps"], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
