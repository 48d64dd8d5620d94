"""mjexplore: MuJoCo simulator and learning stack for lidar-based autonomous exploration."""

import ctypes.util
import os
import sys

__version__ = "0.1.0"

# MuJoCo reads MUJOCO_GL once, at its first import, so the offscreen backend is chosen
# here, before any module imports mujoco: EGL (works on CPU-only machines through Mesa's
# llvmpipe), else OSMesa. A value the user set is kept.
MUJOCO_IMPORTED_FIRST = "mujoco" in sys.modules and "MUJOCO_GL" not in os.environ
if "MUJOCO_GL" not in os.environ:
    if ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
    elif ctypes.util.find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"
    if os.environ.get("MUJOCO_GL") == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    elif os.environ.get("MUJOCO_GL") == "egl":
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
