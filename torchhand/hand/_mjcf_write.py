"""MJCF export: :func:`hand_to_mjcf` and :func:`save_mjcf` (facade and full description: :mod:`torchhand.hand.mjcf`).

Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import hashlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from .._atomic import atomic_text
from ..errors import InputValueError, MissingFileError
from ._mjcf_common import _ROOT_WRAPPER, _mat_to_quat
from ._specs import GEOM_TYPES

if TYPE_CHECKING:  # pragma: no cover
    from .model import HandModel

__all__ = ["hand_to_mjcf", "save_mjcf"]


def _fmt(a) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(a, dtype=np.float64).reshape(-1))


def _set_pose(e: ET.Element, T: np.ndarray) -> None:
    if np.any(T[:3, 3] != 0):
        e.set("pos", _fmt(T[:3, 3]))
    if np.any(T[:3, :3] != np.eye(3)):
        e.set("quat", _fmt(_mat_to_quat(T[:3, :3])))


LOCKED_HALF_WIDTH = 1e-9  # radians / metres: the range written for a joint whose limits coincide

# Written for a link of zero mass (and for the wrapper body): MuJoCo refuses massless moving bodies.
TINY_MASS = 1e-9  # kg
TINY_INERTIA = 1e-12  # kg m^2, each principal moment


def _set_inertial(b: ET.Element, name: str, mass: float, com: np.ndarray, inertia: np.ndarray) -> None:
    """``<inertial pos quat mass diaginertia>`` in the link frame: the principal axes (quat) and moments of the
    inertia about the centre of mass; zero mass: TINY_MASS, TINY_INERTIA at the origin.

    Principal axes are written rather than ``fullinertia`` because MuJoCo diagonalises a ``fullinertia`` with a
    Jacobi iteration that stops at rotations of about 1e-6 rad (its kEigEPS = 1e-12), losing about 1e-9 relative
    precision; NumPy's eigh is exact to rounding. MuJoCo needs principal moments satisfying A + B >= C exactly:
    moments below TINY_INERTIA are raised to it, a violation within rounding (1e-9 relative) is closed, a larger
    one is refused.
    """
    if not mass > 0:
        ET.SubElement(b, "inertial", pos="0 0 0", mass=repr(TINY_MASS), diaginertia=_fmt([TINY_INERTIA] * 3))
        return
    eig, vec = np.linalg.eigh(0.5 * (inertia + inertia.T))  # ascending
    eig = np.maximum(eig, TINY_INERTIA)
    if eig[0] + eig[1] < eig[2]:
        if eig[0] + eig[1] < eig[2] * (1 - 1e-9):
            raise InputValueError(f"link {name!r}: inertia violates the triangle inequality A + B >= C of its "
                                  f"principal moments {eig.tolist()}; MuJoCo cannot load it")
        eig[2] = eig[0] + eig[1]
    if np.linalg.det(vec) < 0:
        vec[:, 0] = -vec[:, 0]
    e = ET.SubElement(b, "inertial", pos=_fmt(com))
    if np.any(vec != np.eye(3)):
        e.set("quat", _fmt(_mat_to_quat(vec)))
    e.set("mass", repr(float(mass)))
    e.set("diaginertia", _fmt(eig))


def hand_to_mjcf(hand: HandModel) -> str:
    """The hand as a self-contained MJCF string that MuJoCo loads (see :mod:`torchhand.hand.mjcf`).

    hand: any HandModel (any device or dtype; written from float64 CPU copies)
    returns: XML text; MuJoCo's qpos = (root position (3), root quaternion wxyz (4), q (D)) gives body poses equal to
        ``hand.forward_kinematics(q, root)``; nq = 7 + D. Every body carries its link's inertial (``link_mass``,
        ``link_com``, ``link_inertia`` as ``<inertial pos quat mass diaginertia>``: principal axes and moments), with
        ``inertiafromgeom="false"``; a massless link, and the ``torchhand_root`` wrapper body, get TINY_MASS (1e-9 kg)
        and TINY_INERTIA (1e-12 kg m^2) at their origin, which MuJoCo needs for moving bodies.
    raises: InputValueError for a mesh MuJoCo cannot compile (fewer than 4 vertices or flat) or an inertia whose
        principal moments violate A + B >= C
    """
    h = hand.to(device="cpu", dtype=torch.float64)
    root = ET.Element("mujoco", model=h.name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")
    _write_custom(root, h)
    mesh_names = _write_meshes(root, h)
    _write_worldbody(ET.SubElement(root, "worldbody"), h, mesh_names)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


def _write_custom(root: ET.Element, h: HandModel) -> None:
    """``<custom>``: side, length, q_rest and the finger annotations, which :func:`torchhand.hand.mjcf.load_mjcf`
    restores."""
    D = h.num_joints
    custom = ET.SubElement(root, "custom")
    ET.SubElement(custom, "text", name="torchhand_side", data=h.side)
    ET.SubElement(custom, "numeric", name="torchhand_length", data=_fmt([h.length]))
    if D:
        ET.SubElement(custom, "numeric", name="torchhand_q_rest", data=_fmt(h.q_rest.numpy()))
    for f, fname in enumerate(h.finger_names):
        links = " ".join(h.link_names[int(i)] for i in h.finger_links[f] if int(i) >= 0)
        flex = " ".join(h.joint_names[int(i)] for i in h.flexion_joints[f] if int(i) >= 0)
        ET.SubElement(custom, "text", name=f"torchhand_finger{f}", data=f"{fname}|{links}|{flex}")
        ET.SubElement(custom, "numeric", name=f"torchhand_finger{f}_frame",
                      data=_fmt(np.concatenate([h.nail_normal[f].numpy(), h.fingertip[f].numpy()])))


def _write_meshes(root: ET.Element, h: HandModel) -> dict[int, str]:
    """``<asset>`` with one inline ``<mesh>`` per distinct mesh (none: no ``<asset>``); returns geom index -> mesh
    name."""
    gm = h.geoms
    asset = ET.SubElement(root, "asset")
    mesh_names, by_hash = {}, {}
    for g in range(gm.link.shape[0]):
        k = int(gm.mesh_index[g])
        if k < 0:
            continue
        V, F = gm.meshes[k][0].numpy(), gm.meshes[k][1].numpy().astype(np.int64)
        key = hashlib.sha1(V.tobytes() + F.tobytes()).hexdigest()
        if key not in by_hash:
            if len(V) < 4 or np.linalg.matrix_rank(V - V.mean(0), tol=1e-9) < 3:
                raise InputValueError(f"hand {h.name!r}: mesh geom {g} on link {h.link_names[int(gm.link[g])]!r} "
                                      "is flat or has fewer than 4 vertices; MuJoCo cannot compile it")
            by_hash[key] = f"mesh{len(by_hash)}"
            ET.SubElement(asset, "mesh", name=by_hash[key], vertex=_fmt(V), face=" ".join(map(str, F.reshape(-1))))
        mesh_names[g] = by_hash[key]
    if not by_hash:
        root.remove(asset)
    return mesh_names


@dataclass(frozen=True)
class _Bodies:
    """What every ``<body>`` is written from: the float64 CPU hand, each link's child links, the link offsets
    (L, 4, 4), each link's geom indices and the mesh name of each mesh geom."""

    h: HandModel
    children: list
    offsets: np.ndarray
    geoms_of: list
    mesh_names: dict


def _write_worldbody(world: ET.Element, h: HandModel, mesh_names: dict[int, str]) -> None:
    """The body tree under ``<worldbody>``, the root carrying the free joint ``root`` (or hanging from the
    ``torchhand_root`` wrapper that carries it)."""
    ch, gm = h.chain, h.geoms
    L, D = h.num_links, h.num_joints
    children = [[] for _ in range(L)]
    for l in range(1, L):
        children[int(ch.link_parent[l])].append(l)
    offsets = ch.link_offset.numpy()
    geoms_of = [[] for _ in range(L)]
    for g in range(gm.link.shape[0]):
        geoms_of[int(gm.link[g])].append(g)
    bodies = _Bodies(h, children, offsets, geoms_of, mesh_names)

    root_has_joints = bool((ch.link_joints[0] < D).any()) if D else False
    # a root link with its own joints (no free joint beside them) or with an offset (a mounted hand) hangs from a
    # wrapper body carrying the free joint, at its offset
    root_offset = not np.allclose(offsets[0], np.eye(4), rtol=0.0, atol=1e-15)
    if root_has_joints or root_offset:
        wrapper = ET.SubElement(world, "body", name=_ROOT_WRAPPER)
        _set_inertial(wrapper, _ROOT_WRAPPER, 0.0, np.zeros(3), np.zeros((3, 3)))
        ET.SubElement(wrapper, "freejoint", name="root")
        _write_body(bodies, wrapper, 0, False)
    else:
        _write_body(bodies, world, 0, True)


def _write_body(bodies: _Bodies, parent_elem: ET.Element, l: int, with_free: bool) -> None:
    """``<body>`` of link ``l`` in ``parent_elem``: pose, inertial, joints, geoms, then its child bodies."""
    h = bodies.h
    b = ET.SubElement(parent_elem, "body", name=h.link_names[l])
    if l or parent_elem.get("name") == _ROOT_WRAPPER:
        _set_pose(b, bodies.offsets[l])
    _set_inertial(b, h.link_names[l], float(h.link_mass[l]), h.link_com[l].numpy(), h.link_inertia[l].numpy())
    if with_free:
        ET.SubElement(b, "freejoint", name="root")
    _write_joints(b, h, l)
    _write_geoms(b, bodies, l)
    for c in bodies.children[l]:
        _write_body(bodies, b, c, False)


def _write_joints(b: ET.Element, h: HandModel, l: int) -> None:
    """The hinge and slide joints of link ``l``, limited, a locked joint widened to +/- LOCKED_HALF_WIDTH."""
    ch, D = h.chain, h.num_joints
    for d in ch.link_joints[l].tolist():
        if d >= D:
            continue
        hinge = int(ch.joint_type[d]) == 0
        j = ET.SubElement(b, "joint", name=h.joint_names[d], type="hinge" if hinge else "slide")
        if hinge and np.any(ch.joint_anchor[d].numpy() != 0):
            j.set("pos", _fmt(ch.joint_anchor[d]))
        j.set("axis", _fmt(ch.joint_axis[d]))
        j.set("limited", "true")
        lo, hi = (float(v) for v in h.joint_limits[d])
        if hi <= lo:              # a locked joint (torchhand.hand.mount): MuJoCo needs range[0] < range[1]
            lo, hi = lo - LOCKED_HALF_WIDTH, hi + LOCKED_HALF_WIDTH
        j.set("range", _fmt(np.array([lo, hi])))


def _write_geoms(b: ET.Element, bodies: _Bodies, l: int) -> None:
    """The collision geoms of link ``l``, named ``<link>_geom<n>``, with MJCF's size semantics."""
    h, gm = bodies.h, bodies.h.geoms
    for n, g in enumerate(bodies.geoms_of[l]):
        gtype = GEOM_TYPES[int(gm.type[g])]
        e = ET.SubElement(b, "geom", name=f"{h.link_names[l]}_geom{n}", type=gtype)
        if gtype == "mesh":
            e.set("mesh", bodies.mesh_names[g])
        else:
            e.set("size", _fmt(gm.size[g][: {"sphere": 1, "capsule": 2, "cylinder": 2, "box": 3}[gtype]]))
        _set_pose(e, gm.pose[g].numpy())


def save_mjcf(hand: HandModel, path) -> Path:
    """Write :func:`hand_to_mjcf` to ``path`` atomically (a temporary file in the same folder, then os.replace).

    returns: the path written; raises MissingFileError when the folder does not exist
    """
    path = Path(path)
    text = hand_to_mjcf(hand)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise MissingFileError(f"path: folder not found: {folder}")
    atomic_text(path, text)
    return path
