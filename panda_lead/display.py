"""Is there a screen? One answer for the viewer, plot windows and MuJoCo's GL backend."""

from __future__ import annotations

import os


def has_display() -> bool:
    """Whether a window can open (an X11 or Wayland display is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def choose_gl_backend() -> None:
    """Headless: offscreen rendering through EGL, where the EGL library exists. MuJoCo reads
    MUJOCO_GL once, at import, so this runs before the first ``import mujoco``; a machine
    without EGL can still simulate, just not render; a MUJOCO_GL already set is kept."""
    if has_display():
        return
    import ctypes.util

    if ctypes.util.find_library("EGL"):
        os.environ.setdefault("MUJOCO_GL", "egl")
