"""An offscreen MuJoCo renderer with a clear error when no GL backend loads."""

from __future__ import annotations

import os

import mujoco

from mjexplore.errors import UserInputError

PACKAGES = {"egl": "libegl1 libegl-mesa0 libgl1-mesa-dri", "osmesa": "libosmesa6"}


def make_renderer(model: mujoco.MjModel, width: int, height: int,
                  max_geom: int = 10000, fast: bool = True) -> mujoco.Renderer:
    """A ``mujoco.Renderer`` of ``width`` x ``height`` pixels; ``fast`` turns shadows,
    reflections, the skybox and multisampling off (MuJoCo's defaults otherwise).

    Raises:
        UserInputError: the GL backend (``MUJOCO_GL``: egl by default, osmesa as the
            fallback) does not load; the message names the Debian packages to install.
    """
    if fast:
        model.vis.quality.offsamples = 0
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    try:
        renderer = mujoco.Renderer(model, height, width, max_geom=max_geom)
    except Exception as exc:  # GL failures surface as many exception types.
        import mjexplore

        if mjexplore.MUJOCO_IMPORTED_FIRST:
            raise UserInputError(
                "offscreen rendering failed: mujoco was imported before mjexplore could choose "
                "its GL backend; set MUJOCO_GL=egl (or osmesa) in the environment, or import "
                "mjexplore before mujoco.") from None
        backend = os.environ.get("MUJOCO_GL", "(unset)")
        raise UserInputError(
            f"offscreen rendering failed with MUJOCO_GL={backend} ({type(exc).__name__}: "
            f"{exc}). Install the Debian packages {PACKAGES['egl']} for EGL (or "
            f"{PACKAGES['osmesa']} and set MUJOCO_GL=osmesa), e.g. with 'make system-deps'."
        ) from None
    if fast:
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION,
                     mujoco.mjtRndFlag.mjRND_SKYBOX):
            renderer.scene.flags[flag] = False
    return renderer


def check_rendering() -> None:
    """Raises :class:`UserInputError` (naming the packages) if offscreen GL cannot start."""
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.1, 0, 0])
    renderer = make_renderer(spec.compile(), 16, 16)
    renderer.close()
