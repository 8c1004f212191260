"""MJCF import: :func:`read_mjcf` reads a file into a :class:`~torchhand.hand._specs.HandSpec` (facade, full
description and :func:`~torchhand.hand.mjcf.load_mjcf`, which builds the model: :mod:`torchhand.hand.mjcf`).

Stages: open and check the file, parse ``<compiler>``, ``<default>`` and assets (:mod:`torchhand.hand._mjcf_parse`),
find the root body, read the body tree (:mod:`torchhand.hand._mjcf_bodies`), then take the finger annotations
torchhand wrote in ``<custom>`` or detect fingers and side (:mod:`torchhand.hand._mjcf_fingers`).
Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputValueError, MissingFileError, UnknownNameError
from ._mjcf_bodies import _add_body, _Tree
from ._mjcf_common import _ROOT_WRAPPER
from ._mjcf_fingers import _detect_fingers, _detect_side
from ._mjcf_parse import _REFUSED_TAGS, _Ctx, _floats, _frame, _parse_header, _where
from ._specs import FingerSpec, HandSpec, InertialSpec

__all__ = ["read_mjcf"]


@dataclass(frozen=True)
class _Annotations:
    """What :func:`torchhand.hand.mjcf.hand_to_mjcf` stores in ``<custom>``: side, length (metres), q_rest (D,) or
    None, fingers."""

    side: str
    length: float
    q_rest: np.ndarray | None
    fingers: list


def _custom_annotations(ctx: _Ctx, root: ET.Element) -> _Annotations | None:
    """Annotations written by :func:`torchhand.hand.mjcf.hand_to_mjcf` in ``<custom>``, or None if there are none."""
    texts, nums = {}, {}
    for c in root.findall("custom"):
        for t in c.findall("text"):
            texts[t.get("name", "")] = t.get("data", "")
        for n in c.findall("numeric"):
            nums[n.get("name", "")] = _floats(ctx, n.attrib, "data", _where(n), default=())
    if "torchhand_side" not in texts:
        return None
    fingers = []
    k = 0
    while f"torchhand_finger{k}" in texts:
        parts = texts[f"torchhand_finger{k}"].split("|")
        frame = nums.get(f"torchhand_finger{k}_frame")
        if len(parts) != 3 or frame is None or len(frame) != 6:
            raise ctx.error(f'<text name="torchhand_finger{k}">', "malformed torchhand finger annotation")
        fingers.append(FingerSpec(parts[0], tuple(parts[1].split()), frame[:3], frame[3:], tuple(parts[2].split())))
        k += 1
    return _Annotations(side=texts["torchhand_side"], length=float(nums.get("torchhand_length", [0.0])[0]),
                        q_rest=nums.get("torchhand_q_rest"), fingers=fingers)


def _open(path: Path, side: str | None) -> tuple[_Ctx, ET.Element]:
    """The parsing context (compiler settings, defaults, mesh assets read) and the ``<mujoco>`` element."""
    if side is not None and side not in ("right", "left", "none"):
        raise InputValueError(f"side: expected 'right', 'left' or 'none', got {side!r}")
    if not path.is_file():
        raise MissingFileError(f"MJCF file not found: {path}")
    try:
        xml_root = ET.parse(path).getroot()
    except ET.ParseError as err:
        raise FileFormatError(f"{path}: malformed XML: {err}") from None
    ctx = _Ctx(path=path)
    if xml_root.tag != "mujoco":
        raise ctx.error(f"<{xml_root.tag}>", "the root element must be <mujoco>")
    for tag in _REFUSED_TAGS:
        bad = xml_root.find(f".//{tag}")
        if bad is not None:
            raise ctx.error(_where(bad), f"<{tag}> is not supported; expand it first (e.g. save MuJoCo's "
                                         "compiled model with mj_saveLastXML)")
    _parse_header(ctx, xml_root)
    return ctx, xml_root


def _find_body(elem: ET.Element, cls: str, name: str):
    """(the body named ``name`` below ``elem``, the childclass in force there) or None; depth first."""
    for b in elem:
        if b.tag not in ("body", "frame"):
            continue
        bcls = b.get("childclass", cls)
        if b.tag == "body" and b.get("name") == name:
            return b, cls
        hit = _find_body(b, bcls, name)
        if hit is not None:
            return hit
    return None


def _root_body(ctx: _Ctx, xml_root: ET.Element, root_body: str | None):
    """(root body element, childclass in force there, its offset (4, 4) in the FK's root frame)."""
    worlds = xml_root.findall("worldbody")  # MuJoCo merges repeated sections
    bodies = [b for w in worlds for b in w.findall("body")]
    if not bodies:
        raise ctx.error("<worldbody>", "no body found")
    root_offset = np.eye(4)
    if root_body is not None:
        hit = next((h for h in (_find_body(w, "main", root_body) for w in worlds) if h is not None), None)
        if hit is None:
            known = [b.get("name") for w in worlds for b in w.iter("body") if b.get("name")]
            raise UnknownNameError(f"{ctx.path}: root_body {root_body!r} not found; bodies: {', '.join(known)}")
        rb, cls = hit
    else:
        rb, cls = bodies[0], "main"
        inner = rb.findall("body")
        if rb.get("name") == _ROOT_WRAPPER and len(inner) == 1:
            # the wrapper carries the free joint (the FK root); the root link's pose in it is its offset
            cls, rb = rb.get("childclass", cls), inner[0]
            root_offset = _frame(ctx, rb.attrib, _where(rb))
    return rb, cls, root_offset


def _inertial_specs(ctx: _Ctx, tree: _Tree) -> list[InertialSpec]:
    """Every link's inertial, scaled to the compiler's settotalmass (MuJoCo's mj_setTotalmass over the hand)."""
    inertials = tree.inertials
    if ctx.settotalmass > 0:  # MuJoCo's mj_setTotalmass over the hand's bodies
        total = sum(m for m, _, _ in inertials)
        k = ctx.settotalmass / total if total > 0 else 0.0
        inertials = [(m * k, c, I * k) for m, c, I in inertials] if k > 0 else inertials
    return [InertialSpec(l.name, m, c, I) for l, (m, c, I) in zip(tree.links, inertials)]


def read_mjcf(path, *, root_body: str | None = None, side: str | None = None, name: str | None = None) -> HandSpec:
    """Read a hand from an MJCF file (see :mod:`torchhand.hand.mjcf` for what is supported and the heuristics).

    path:      the .xml file; mesh files are found through ``<compiler meshdir/assetdir>`` relative to it
    root_body: name of the body that becomes link 0 (default: the first body under ``<worldbody>``); its world pose
               (before its own joints) is the FK's ``root`` input
    side:      "right" | "left" | "none"; default: from the file name, model name or body-name prefixes
    name:      model name; default: ``<mujoco model=...>`` or the file name
    returns: HandSpec; joints in MuJoCo's qpos order (free joint excluded)
    raises: MissingFileError (file or mesh file missing), FileFormatError (malformed XML, unsupported or invalid
            element, naming the file and the element), UnknownNameError (``root_body`` not found)
    """
    path = Path(path)
    ctx, xml_root = _open(path, side)
    rb, cls, root_offset = _root_body(ctx, xml_root, root_body)
    tree = _Tree()
    _add_body(ctx, tree, rb, -1, root_offset, cls)

    stored = _custom_annotations(ctx, xml_root)
    if stored is not None:
        fingers, length = stored.fingers, stored.length
        side = side or stored.side
        q_rest = stored.q_rest
        if q_rest is not None and len(q_rest) != len(tree.joints):
            raise ctx.error('<numeric name="torchhand_q_rest">', f"expected {len(tree.joints)} values")
    else:
        fingers, length = _detect_fingers(tree)
        q_rest = None
    model_name = xml_root.get("model") or path.stem
    side = side or _detect_side(path, model_name, tree.links)
    return HandSpec(name=name or model_name, links=tuple(tree.links), joints=tuple(tree.joints),
                    geoms=tuple(tree.geoms), fingers=tuple(fingers), side=side, length=length, q_rest=q_rest,
                    inertials=tuple(_inertial_specs(ctx, tree)))
