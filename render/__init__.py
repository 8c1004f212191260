"""Offscreen rendering and plots of hand motion (installed as ``torchhand.render``).

Drawing: :func:`render_frames` / :func:`write_video` turn :class:`Clip` s (built by :func:`clip_from_solution` from a
result directory, or :func:`clip_from_hand` from joint angles and wrist poses) into frames and mp4 / GIF / PNG files;
:func:`render_hand_motion` draws a hand alone. Result directories are read by :func:`torchhand.io.result.load_result`
(the format is ``docs/result_format.md``).
Plots: :mod:`torchhand.render.plots`. The ``torchhand render`` and ``torchhand plot`` commands call
:mod:`torchhand.render.jobs`.

pyrender (and PyOpenGL) are imported only when a renderer is created; only that entry point chooses
``PYOPENGL_PLATFORM`` (see :mod:`torchhand.render.backend`). The boundary type is NumPy: frames are (H, W, 3) uint8.
Conventions (see :mod:`torchhand.conventions`): world z-up, metres, newtons, column-vector 4x4 transforms.
"""

from __future__ import annotations

_LAZY = {
    "RenderBackendError": ".backend",
    "Camera": ".camera",
    "frame_points": ".camera",
    "Clip": ".clip",
    "clip_from_hand": ".clip",
    "clip_from_solution": ".clip",
    "RenderOptions": ".compose",
    "render_frames": ".compose",
    "render_hand_motion": ".compose",
    "write_video": ".compose",
    "ClipRenderer": ".renderer",
    "Style": ".renderer",
    "render_result": ".jobs",
    "plot_result": ".jobs",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'torchhand.render' has no attribute {name!r}")


__all__ = list(_LAZY)
