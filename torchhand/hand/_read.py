"""Read a hand file (MJCF or URDF) into a :class:`~torchhand.hand._specs.HandSpec` through MuJoCo's compiler.

:func:`read_hand_file` compiles the file (:mod:`torchhand.hand._compile`), reads the tree below the hand's root body
(:mod:`torchhand.hand._compiled_read`), then takes the finger annotations torchhand wrote in ``<custom>`` or finds
fingers, thumb and side by topology (:mod:`torchhand.hand._topology`). Conventions: metres, radians, quaternions
wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import re
from pathlib import Path

from ..errors import InputValueError
from ._compile import compile_file
from ._compiled_read import custom_annotations, read_compiled
from ._specs import HandSpec
from ._topology import find_fingers

__all__ = ["read_hand_file"]


def read_hand_file(path, *, root_body: str | None = None, side: str | None = None,
                   name: str | None = None) -> HandSpec:
    """Read a hand from an MJCF or URDF file (see :mod:`torchhand.hand.mjcf` for what is read and the rules).

    path:      the .xml or .urdf file (told apart by the root element, ``<mujoco>`` or ``<robot>``)
    root_body: name of the body that becomes link 0 (default: the top-level body with the most joints below it);
               its world pose (before its own joints) is the FK's ``root`` input
    side:      "right" | "left" | "none"; default: the stored annotation, else the thumb's side (topology), else
               "right"/"left" in the file or model name
    name:      model name; default: the model's name or the file name
    returns: HandSpec; joints in MuJoCo's qpos order (free joint excluded)
    raises: MissingFileError (file or mesh file missing), FileFormatError (anything MuJoCo refuses, or an
            unsupported element, on one line), UnknownNameError (``root_body`` not found)
    """
    if side is not None and side not in ("right", "left", "none"):
        raise InputValueError(f"side: expected 'right', 'left' or 'none', got {side!r}")
    path = Path(path)
    model = compile_file(path)
    tree = read_compiled(model, path, root_body)
    stored = custom_annotations(model, len(tree.joints), path)
    if stored is not None:
        stored_side, length, q_rest, fingers = stored
        side = side or stored_side
    else:
        topo = find_fingers(tree)
        fingers, length, q_rest = topo.fingers, topo.length, None
        side = side or (topo.side if topo.side != "none" else _side_from_names(path, tree.name))
    return HandSpec(name=name or tree.name, links=tree.links, joints=tree.joints, geoms=tree.geoms,
                    fingers=tuple(fingers), side=side, length=length, q_rest=q_rest, inertials=tree.inertials,
                    couplings=tree.couplings)


def _side_from_names(path: Path, model_name: str) -> str:
    for text in (path.stem, model_name):
        m = re.search(r"(?:^|[^a-z])(right|left)(?:[^a-z]|$)", text.lower())
        if m:
            return m.group(1)
    return "none"
