"""MuJoCo's OpenGL back end: chosen once, before mujoco is first imported, so that nothing needs GL at import.

MuJoCo reads the environment variable ``MUJOCO_GL`` once, when it is first imported, and with ``egl`` (or
``osmesa``) it loads PyOpenGL's EGL (OSMesa) bindings right then: without ``libEGL`` that import dies
(``AttributeError: 'NoneType' object has no attribute 'eglQueryString'``), so a blind ``MUJOCO_GL=egl`` breaks
every program that imports mujoco, even one that never renders. :func:`select_backend` therefore chooses:

* ``MUJOCO_GL`` already set: it is kept, unless it names ``egl`` or ``osmesa`` and that library cannot be loaded;
  then mujoco is imported with OpenGL off (``MUJOCO_GL=disabled``) and asking for images says why;
* unset: ``egl`` when ``libEGL`` loads (Mesa's llvmpipe renders on the CPU, no GPU needed), else ``osmesa`` when
  ``libOSMesa`` loads, else it stays unset (mujoco imports fine; only rendering needs a back end).

Every module that imports mujoco for rendering calls :func:`select_backend` before its ``import mujoco`` (it does
nothing once mujoco is loaded). The choice is written to ``os.environ``, so worker processes inherit it.
:func:`render_problem` says in one line why images cannot be made here (``None`` when they can, as far as can be
told without making a context); :func:`require_rendering` raises it as :class:`~graspgen.errors.RenderError`.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys

from graspgen.errors import RenderError

__all__ = ["HOW_TO_FIX", "backend_in_use", "render_problem", "require_rendering", "select_backend"]

_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}
"""Headless back end -> the library PyOpenGL loads for it (``lib<name>.so[.N]``)."""
_OFF = ("disable", "disabled", "off", "false", "0")
"""MUJOCO_GL values with which mujoco loads no OpenGL at all."""
_UNUSABLE = "GRASPGEN_MUJOCO_GL_UNUSABLE"
"""Set by :func:`select_backend` (and inherited by workers): the MUJOCO_GL it turned off because its library
could not be loaded."""

HOW_TO_FIX = (
    "install Mesa EGL (apt install libegl1 libgl1-mesa-dri) or OSMesa (apt install libosmesa6, and set "
    "MUJOCO_GL=osmesa), or turn images off (scenes.cameras.render: false)"
)
"""The two ways out when no OpenGL back end can render."""


@functools.cache
def _loadable(backend: str) -> bool:
    """Whether the library of a headless back end loads, tried the way PyOpenGL tries it (lib<name>.so[.N])."""
    base = f"lib{_LIBRARIES[backend]}.so"
    for filename in (base, *(f"{base}.{i}" for i in range(9, -1, -1))):
        try:
            ctypes.CDLL(filename, mode=ctypes.RTLD_GLOBAL)
        except OSError:
            continue
        return True
    return False


def _linux() -> bool:
    return sys.platform.startswith("linux")


def select_backend() -> str | None:
    """Choose MuJoCo's OpenGL back end (see the module text) unless mujoco is already imported.

    Returns ``MUJOCO_GL`` as mujoco reads (or read) it: ``egl``, ``osmesa``, another value, or None (unset).
    """
    if "mujoco" in sys.modules or not _linux():
        return os.environ.get("MUJOCO_GL")
    asked = os.environ.get("MUJOCO_GL", "").strip().lower()
    if not asked:
        for backend in _LIBRARIES:
            if _loadable(backend):
                os.environ["MUJOCO_GL"] = backend
                return backend
        return None
    if asked in _LIBRARIES and not _loadable(asked):
        os.environ[_UNUSABLE] = asked
        os.environ["MUJOCO_GL"] = "disabled"
    return os.environ["MUJOCO_GL"]


def backend_in_use() -> str:
    """The MUJOCO_GL value mujoco uses (read when it was imported), lower case; '' when unset (GLFW)."""
    module = sys.modules.get("mujoco.rendering.classic.gl_context")
    used = getattr(module, "_MUJOCO_GL", None)
    if used is not None:
        return used
    return os.environ.get("MUJOCO_GL", "").strip().lower()


def render_problem() -> str | None:
    """One line saying why MuJoCo cannot render images in this process, or None when it should be able to.

    Only libraries and settings are looked at (no OpenGL context is made), so it is cheap; a context that still
    fails to start is reported by :class:`~graspgen.sim.render.SceneRenderer`.
    """
    select_backend()
    if not _linux():
        return None
    backend = backend_in_use()
    if backend in _LIBRARIES:
        if _loadable(backend):
            return None
        why = f"MUJOCO_GL={backend} but lib{_LIBRARIES[backend]} cannot be loaded"
    elif backend in _OFF:
        asked = os.environ.get(_UNUSABLE)
        if asked not in _LIBRARIES or _loadable(asked):
            return (
                f"cannot render images: MUJOCO_GL={backend} turns OpenGL off; unset it (or set MUJOCO_GL=egl or "
                "osmesa) before Python starts, or turn images off (scenes.cameras.render: false)"
            )
        why = f"MUJOCO_GL={asked} but lib{_LIBRARIES[asked]} cannot be loaded"
    elif os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None  # GLFW (or GLX) with a display
    elif any(_loadable(b) for b in _LIBRARIES):
        setting = f"MUJOCO_GL={backend}" if backend else "MUJOCO_GL unset"
        return (
            f"cannot render images: mujoco was imported ({setting}: GLFW, which needs a display) before "
            "graspgen.sim.gl chose a headless back end; import graspgen before mujoco, or set MUJOCO_GL=egl (or "
            "osmesa) before Python starts, or turn images off (scenes.cameras.render: false)"
        )
    else:
        why = "no headless OpenGL library: neither libEGL nor libOSMesa can be loaded (and there is no display)"
    return f"cannot render images: {why}; {HOW_TO_FIX}"


def require_rendering() -> None:
    """Raise :class:`~graspgen.errors.RenderError` (one line, see :func:`render_problem`) when images cannot be
    made here."""
    problem = render_problem()
    if problem is not None:
        raise RenderError(problem)


select_backend()  # on import, so that importing this module first is enough (it must precede mujoco's import)
