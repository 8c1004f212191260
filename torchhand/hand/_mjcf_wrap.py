"""A result's ``hand.xml`` for an MJCF hand: the user's own file, its root body hung from a free joint.

:func:`wrap_user_mjcf` writes the file the user gave (``[[hands]] model`` or ``--hand``) with three changes, so that
MuJoCo replays a result by setting ``qpos`` and keeps everything else the user's model has (tendons and joint
couplings, actuators, contact exclusions, classes, options, the mesh files themselves):

* its root body (the first body under ``<worldbody>``, which must be the root :func:`~torchhand.hand.mjcf.load_mjcf` takes) is moved
  into a new body ``torchhand_root`` carrying a free joint ``root``, and its pose becomes the mounted root offset
  (:mod:`torchhand.hand.mount`: ``F⁻¹`` times its own): ``qpos = (wrist position (3), wrist quaternion wxyz (4),
  the model's joints)`` then gives the hand of the result, the wrist track being the pose of the hand frame;
* torchhand's annotations are added in ``<custom>`` (side, length, rest pose, fingers with their pads and nails),
  so :func:`torchhand.load_result` reads the same hand model back;
* the asset files it names (meshes, textures, height fields, skins) are copied into a folder beside it
  (``<stem>_assets/``) and ``<compiler meshdir texturedir assetdir>`` point there; ``<key>`` rows gain the free
  joint's 7 ``qpos`` and 6 ``qvel`` values (identity pose, at rest) in front.

Joints the mount locks (the Shadow wrist) keep the user's range; the result's ``q`` holds them at their rest
angle. A URDF file, a file with ``<include>`` elements, or one whose first body is not the hand's root (a scene with
an object first) cannot be carried this way: :func:`wrap_user_mjcf` returns None and the caller writes torchhand's
own MJCF (:func:`torchhand.hand.mjcf.hand_to_mjcf`, meshes inline) instead.
"""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from .._atomic import atomic_text
from ._mjcf_common import _ROOT_WRAPPER
from ._mjcf_write import TINY_INERTIA, TINY_MASS, _fmt, _set_pose, hand_to_mjcf

if TYPE_CHECKING:  # pragma: no cover
    from .model import HandModel

__all__ = ["wrap_user_mjcf"]

_POSE_ATTRS = ("pos", "quat", "euler", "axisangle", "xyaxes", "zaxis")
_ASSET_DIRS = {"mesh": "meshdir", "skin": "meshdir", "hfield": "meshdir", "texture": "texturedir"}


def wrap_user_mjcf(src, hand: HandModel, out_xml) -> Path | None:
    """Write ``src`` (the user's MJCF hand) as ``out_xml`` with a free-joint wrapper at ``hand``'s mount (module
    docstring). ``hand``: the mounted model the synthesis used, loaded from ``src``. Returns the asset folder
    written (or ``out_xml``'s folder when there were no assets), or None when the file cannot be carried (module
    docstring) and nothing was written."""
    src, out_xml = Path(src), Path(out_xml)
    root = ET.parse(src).getroot()
    if root.tag != "mujoco" or root.find(".//include") is not None:
        return None
    h = hand.to(device="cpu", dtype=torch.float64)
    worlds = root.findall("worldbody")
    world = next((w for w in worlds if w.find("body") is not None), None)
    if world is None or world.find("body").get("name") != h.link_names[0]:
        return None
    assets = out_xml.with_name(out_xml.stem + "_assets")
    _copy_assets(root, src.parent, assets)
    rb = world.find("body")
    first = list(world).index(rb)
    index_among_bodies = [e for e in world if e.tag == "body"].index(rb)
    for a in _POSE_ATTRS:
        rb.attrib.pop(a, None)
    _set_pose(rb, h.chain.link_offset[0].numpy())
    wrapper = ET.Element("body", name=_ROOT_WRAPPER)
    ET.SubElement(wrapper, "inertial", pos="0 0 0", mass=repr(TINY_MASS), diaginertia=_fmt([TINY_INERTIA] * 3))
    ET.SubElement(wrapper, "freejoint", name="root")
    world.remove(rb)
    wrapper.append(rb)
    world.insert(first, wrapper)
    for key in root.iter("key"):
        if index_among_bodies != 0:
            continue
        if key.get("qpos"):
            key.set("qpos", "0 0 0 1 0 0 0 " + key.get("qpos"))
        if key.get("qvel"):
            key.set("qvel", "0 0 0 0 0 0 " + key.get("qvel"))
    if index_among_bodies != 0:                 # the free joint's qpos is not first: drop rows that would misfit
        for kf in root.findall("keyframe"):
            root.remove(kf)

    # torchhand's annotations, as its own writer makes them
    ours = ET.fromstring(hand_to_mjcf(h)).find("custom")
    custom = root.find("custom")
    if custom is None:
        custom = ET.Element("custom")
        root.insert(1 if root.find("compiler") is not None else 0, custom)
    for e in list(ours):
        custom.append(e)
    ET.indent(root)
    atomic_text(out_xml, ET.tostring(root, encoding="unicode") + "\n")
    return assets if assets.is_dir() else out_xml.parent


def _copy_assets(root: ET.Element, base: Path, dest: Path) -> None:
    """Copy every file an ``<asset>`` element names into ``dest`` (its path relative to its folder kept) and point
    ``<compiler>`` there."""
    compiler = root.find("compiler")
    dirs = {k: (compiler.get(k) if compiler is not None else None) for k in ("meshdir", "texturedir", "assetdir")}
    copied = False
    for asset in root.iter("asset"):
        for e in asset:
            f = e.get("file")
            if not f:
                continue
            p = Path(f)
            if not p.is_absolute():
                d = dirs.get(_ASSET_DIRS.get(e.tag, "assetdir")) or dirs["assetdir"]
                p = base / d / f if d is not None else base / f
            target = dest / f if not Path(f).is_absolute() else dest / p.name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(p, target)
            if Path(f).is_absolute():
                e.set("file", p.name)
            copied = True
    if not copied:
        return
    if compiler is None:
        compiler = ET.Element("compiler")
        root.insert(0, compiler)
    for k in ("meshdir", "texturedir", "assetdir"):
        compiler.set(k, dest.name)


def _same_model(a: HandModel, b: HandModel, tol: float = 1e-9) -> bool:
    """Whether two hand models have the same links, joints and kinematics at their rest pose (FK within tol)."""
    if a.link_names != b.link_names or a.joint_names != b.joint_names:
        return False
    a, b = a.to(device="cpu", dtype=torch.float64), b.to(device="cpu", dtype=torch.float64)
    q = a.q_rest[None]
    return bool(np.abs((a.forward_kinematics(q) - b.forward_kinematics(q)).numpy()).max() <= tol)
