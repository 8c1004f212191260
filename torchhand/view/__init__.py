"""``torchhand view``: a result directory in the browser, as an interactive 3-D scene served by viser.

The object (posed per frame), the table, every solution's hands (hand.xml's collision geoms posed by forward
kinematics), contact points and force arrows, and a timeline: a frame slider, play/pause at the result's frame
rate, and the checker's verdict of every frame (a line for the current frame, a pass/fail strip over all frames).

Modules, bottom to top: :mod:`.frames` (a result as per-frame NumPy geometry in frozen dataclasses),
:mod:`.verdict` (the checker's per-frame verdicts), :mod:`.scene` (viser nodes, posed per frame), :mod:`.gui`
(the panel and playback), :mod:`.server` (:func:`serve` and :class:`ViewerHandle`). Conventions: world z-up,
metres, newtons, ``T_world_frame`` column-vector poses, frames first (T, ...). viser is imported only by
:func:`serve`; ``docs/view.md`` has the command and the remote use.

Example::

    import torchhand.view
    h = torchhand.view.serve("out/box-turn", port=0, block=False)
    print(h.url); h.set_frame(10); h.set_solution(2); h.stop()
"""

from __future__ import annotations

import importlib

from .defaults import DEFAULT_HOST, DEFAULT_PORT

__all__ = ["serve", "ViewerHandle", "PortInUseError", "ViewData", "load_view", "DEFAULT_HOST", "DEFAULT_PORT"]

_LAZY = {"serve": ".server", "ViewerHandle": ".server", "PortInUseError": ".server", "ViewData": ".frames",
         "load_view": ".frames"}


def __getattr__(name: str):
    """The public names, imported on first use (the command line's --help does not load NumPy or trimesh)."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
