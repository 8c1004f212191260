"""MJCF import and export of hand models (MuJoCo's XML format), without MuJoCo at run time.

Import: :func:`load_mjcf` (also ``HandModel.from_mjcf``)
    Parses the file with :mod:`xml.etree` and builds a :class:`~torchhand.hand.model.HandModel` whose forward
    kinematics equals MuJoCo's body poses (``data.xpos``, ``data.xmat``) for the same joint values.

    * ``<compiler>``: ``angle`` (MuJoCo's default is **degree**; it scales hinge/ball ranges and ``axisangle`` /
      ``euler`` angles), ``meshdir`` / ``assetdir`` (relative to the XML file), ``eulerseq``, ``autolimits``.
    * ``<default>`` classes with nesting, ``class=`` on elements and ``childclass`` on bodies and frames.
    * Orientations in every MJCF form: ``quat`` (wxyz), ``axisangle``, ``euler`` (with ``eulerseq``), ``xyaxes``,
      ``zaxis``; ``<frame>`` elements compose into their children.
    * Links: every ``<body>`` below the root, depth first (MuJoCo's body order); bodies without joints are links
      with fixed offsets. Joints, in MuJoCo's qpos order: ``hinge`` and ``slide`` map one to one (``pos`` = anchor);
      ``ball`` becomes three hinges ``<name>_x``, ``<name>_y``, ``<name>_z`` about the body axes (limits +/- the
      ball's range); a ``free`` joint is skipped on the root body and refused elsewhere. Limits: ``range`` where the
      joint is limited (``limited="true"``, or ``auto`` with a range); unlimited joints get +/- pi (hinge) or
      +/- 1 m (slide). A non-zero ``ref`` is refused (the kernels have no joint offset).
    * The root: the first body under ``<worldbody>`` (or ``root_body``). Link 0's parent frame is the FK's ``root``
      input, so the root body's own ``pos``/orientation (and its ancestors) are not part of the model: the caller
      passes the root body's world pose (MuJoCo's ``data.xpos/xmat`` of that body, before any of its own joints)
      as ``root``. A body named ``torchhand_root`` with a free joint (written by :func:`hand_to_mjcf` when the root
      link has joints of its own) is looked through.
    * Geometry: collision geoms only. A geom with ``contype="0"`` and ``conaffinity="0"`` is visual and skipped
      (meshes used only by visual geoms are not read, though their files must exist, as for MuJoCo). Capsule,
      cylinder, box, sphere (``fromto`` included) keep MJCF's size semantics; ellipsoids become meshes (a scaled
      icosphere); plane, hfield and sdf geoms and primitives fitted to meshes are refused. Mesh assets are read
      with trimesh from ``meshdir`` (or given inline by ``vertex``/``face``; a vertex list alone means its convex
      hull), scaled by ``scale``, exact duplicate vertices merged.
    * Mesh frames: MuJoCo moves a mesh's vertices into the mesh's inertial frame and moves the geom frame by the
      inverse (``model.mesh_pos``, ``model.mesh_quat``). Here the vertices stay in the mesh file's frame and the
      geom pose is the one written in the XML, so the geometry in the body frame is identical to MuJoCo's:
      ``GeomSpec.pose @ T(mesh_pos, mesh_quat) == T(model.geom_pos, model.geom_quat)``.
    * ``<include>``, ``<replicate>``, ``<attach>``, ``<composite>`` and ``<flexcomp>`` are refused with a clear
      error; tendons, equalities, actuators, sites, cameras, lights and inertials are ignored.

    Fingers (heuristic; a file written by :func:`hand_to_mjcf` stores its annotations in ``<custom>`` and those win):
    every leaf body whose chain below the nearest branching body (a body with two or more child bodies, e.g. the
    palm) carries at least two hinge joints is a finger. Its links are the bodies of that chain that have joints,
    plus the leaf when it has none, last four kept; the distal link is the leaf. All directions are taken at q = 0
    in the distal link's frame:

    * finger direction ``d``: from the nearest ancestor origin that differs from the distal link's origin to it;
    * flexion joints: the (up to three most distal) hinges of the chain whose axis is parallel (within 25 degrees)
      to the last hinge's axis, proximal first;
    * tip: the point of the distal link's collision geometry farthest along ``d`` (its support point);
    * nail normal: ``d x a`` with ``a`` the last flexion axis, signed so that it points away from the side the
      finger flexes to (positive angles flex when the joint range lies mostly above zero), orthogonal to ``d``;
    * name: the common prefix of the finger's link names without a side prefix (``rh_ff...`` -> ``ff``), else the
      leaf's name;
    * ``length``: the largest distance at q = 0 from a finger's branching body to its tip.

    ``side``: the ``side`` argument, else "right"/"left" in the file name, the model name, or the body-name prefixes
    ``rh_``/``lh_``; else "none".

Export: :func:`hand_to_mjcf` (also ``HandModel.to_mjcf``) and :func:`save_mjcf`
    A self-contained MJCF string for any hand: bodies named ``link_names``, hinge/slide joints named ``joint_names``
    with ``limited="true"`` ranges from ``joint_limits``, ``angle="radian"``, an ``<inertial>`` on every body
    (1 g, 1e-7 kg m^2), the root body at the identity carrying ``<freejoint name="root"/>``, so that for
    ``qpos = (root position (3), root quaternion wxyz (4), q (D))`` MuJoCo's body poses equal
    ``hand.forward_kinematics(q, root)``. (qpos[7:] follows joint_names exactly when joints are listed depth first
    along the tree, as in the default hand and every loaded hand; otherwise map through ``model.jnt_qposadr``.) When
    the root link has joints of its own, MuJoCo allows no free joint beside them, and an extra top body
    ``torchhand_root`` carries the free joint. Geoms keep their size and pose; meshes are written inline
    (``<mesh vertex=... face=...>``): MuJoCo re-centres them as above, which leaves the world geometry unchanged
    (meshes MuJoCo cannot compile, i.e. flat or with fewer than 4 vertices, are refused). Side, length, q_rest and the
    finger annotations go into ``<custom>`` so that :func:`load_mjcf` restores them.

Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import FileFormatError, InputValueError, MissingFileError, UnknownNameError
from .model import GEOM_TYPES, FingerSpec, GeomSpec, HandModel, JointSpec, LinkSpec, build_hand_model

__all__ = ["load_mjcf", "hand_to_mjcf", "save_mjcf"]

_UNLIMITED = {"hinge": (-math.pi, math.pi), "slide": (-1.0, 1.0)}  # radians, metres
_ROOT_WRAPPER = "torchhand_root"
_REFUSED_TAGS = ("include", "replicate", "attach", "composite", "flexcomp")
_FLEX_PARALLEL_COS = math.cos(math.radians(25.0))


# ----------------------------------------------------------------------------------------------------------------
# Rotations (NumPy, float64, wxyz quaternions)
# ----------------------------------------------------------------------------------------------------------------
def _quat_to_mat(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _mat_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method: stable for every angle)."""
    tr = np.trace(R)
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2 * math.sqrt(max(1 + tr, 0.0))
        q = np.array([s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i, j, l = k - 1, k % 3, (k + 1) % 3
        s = 2 * math.sqrt(max(1 + R[i, i] - R[j, j] - R[l, l], 0.0))
        q = np.empty(4)
        q[0] = (R[l, j] - R[j, l]) / s
        q[1 + i] = s / 4
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + l] = (R[l, i] + R[i, l]) / s
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def _axis_angle(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return _quat_to_mat(np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a]))


def _z_to_vec(v) -> np.ndarray:
    """MuJoCo's ``mju_quatZ2Vec``: the minimal rotation taking +z to ``v`` (pi about x when v is -z)."""
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if n < 1e-15:
        return np.eye(3)
    v = v / n
    ax = np.cross([0.0, 0.0, 1.0], v)
    s = np.linalg.norm(ax)
    if s < 1e-15:
        return np.eye(3) if v[2] > 0 else _quat_to_mat([0.0, 1.0, 0.0, 0.0])
    return _axis_angle(ax / s, math.atan2(s, v[2]))


def _pose(R=None, p=None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if p is not None:
        T[:3, 3] = p
    return T


# ----------------------------------------------------------------------------------------------------------------
# Parsing context and attribute helpers
# ----------------------------------------------------------------------------------------------------------------
@dataclass
class _Ctx:
    path: Path
    angle: float = math.pi / 180  # MuJoCo's default unit is the degree
    eulerseq: str = "xyz"
    autolimits: bool = True
    meshdir: Path = Path(".")
    defaults: dict = field(default_factory=dict)  # class -> tag -> attrs
    mesh_assets: dict = field(default_factory=dict)  # name -> (attrs, class)
    mesh_cache: dict = field(default_factory=dict)

    def error(self, where: str, msg: str) -> FileFormatError:
        return FileFormatError(f"{self.path}: {where}: {msg}")


def _where(elem: ET.Element) -> str:
    name = elem.get("name")
    return f'<{elem.tag} name="{name}">' if name else f"<{elem.tag}>"


def _floats(ctx: _Ctx, attrs: dict, key: str, where: str, n=None, default=None) -> np.ndarray | None:
    """Attribute ``key`` as floats; ``n`` an int or a tuple of allowed counts."""
    if key not in attrs:
        return None if default is None else np.asarray(default, dtype=np.float64)
    try:
        v = np.array([float(s) for s in attrs[key].split()], dtype=np.float64)
    except ValueError:
        raise ctx.error(where, f"attribute {key}={attrs[key]!r} is not a list of numbers") from None
    counts = (n,) if isinstance(n, int) else n
    if counts is not None and len(v) not in counts:
        raise ctx.error(where, f"attribute {key} expects {' or '.join(map(str, counts))} numbers, got {len(v)}")
    if not np.isfinite(v).all():
        raise ctx.error(where, f"attribute {key}={attrs[key]!r} is not finite")
    return v


def _resolve(ctx: _Ctx, elem: ET.Element, cls: str) -> dict:
    """Attributes of ``elem`` over the defaults of its class (its own ``class=`` or the inherited childclass)."""
    cls = elem.get("class", cls)
    if cls not in ctx.defaults:
        raise ctx.error(_where(elem), f"unknown default class {cls!r}; known: {', '.join(ctx.defaults)}")
    attrs = dict(ctx.defaults[cls].get(elem.tag, {}))
    attrs.update(elem.attrib)
    attrs.pop("class", None)
    return attrs


def _frame(ctx: _Ctx, attrs: dict, where: str) -> np.ndarray:
    """The (4, 4) pose given by pos and one orientation attribute (MuJoCo: an alternative beats ``quat``)."""
    pos = _floats(ctx, attrs, "pos", where, 3, default=(0.0, 0.0, 0.0))
    alts = [k for k in ("axisangle", "xyaxes", "zaxis", "euler") if k in attrs]
    if len(alts) > 1:
        raise ctx.error(where, f"more than one orientation given ({', '.join(alts)})")
    if alts == ["axisangle"]:
        v = _floats(ctx, attrs, "axisangle", where, 4)
        if np.linalg.norm(v[:3]) < 1e-15:
            raise ctx.error(where, "axisangle has a zero axis")
        R = _axis_angle(v[:3], v[3] * ctx.angle)
    elif alts == ["xyaxes"]:
        v = _floats(ctx, attrs, "xyaxes", where, 6)
        x = v[:3] / np.linalg.norm(v[:3])
        y = v[3:] - x * (x @ v[3:])
        if np.linalg.norm(y) < 1e-15:
            raise ctx.error(where, "xyaxes are parallel")
        y = y / np.linalg.norm(y)
        R = np.stack([x, y, np.cross(x, y)], axis=1)
    elif alts == ["zaxis"]:
        R = _z_to_vec(_floats(ctx, attrs, "zaxis", where, 3))
    elif alts == ["euler"]:
        e = _floats(ctx, attrs, "euler", where, 3) * ctx.angle
        R = np.eye(3)
        for ch, ang in zip(ctx.eulerseq, e):
            Ri = _axis_angle(np.eye(3)["xyz".index(ch.lower())], ang)
            R = R @ Ri if ch.islower() else Ri @ R  # lower case: moving axes (post-multiply); upper: fixed axes
    elif "quat" in attrs:
        q = _floats(ctx, attrs, "quat", where, 4)
        if np.linalg.norm(q) < 1e-15:
            raise ctx.error(where, "quat is zero")
        R = _quat_to_mat(q)
    else:
        R = np.eye(3)
    return _pose(R, pos)


# ----------------------------------------------------------------------------------------------------------------
# Defaults, compiler, assets
# ----------------------------------------------------------------------------------------------------------------
def _parse_defaults(ctx: _Ctx, elem: ET.Element, parent: dict, top: bool) -> None:
    name = elem.get("class", "main" if top else None)
    if name is None:
        raise ctx.error("<default>", "a nested default class needs a class= name")
    if name in ctx.defaults:
        raise ctx.error(f'<default class="{name}">', "duplicate default class")
    mine = {tag: dict(attrs) for tag, attrs in parent.items()}
    for child in elem:
        if child.tag != "default":
            mine.setdefault(child.tag, {}).update(child.attrib)
    ctx.defaults[name] = mine
    for child in elem:
        if child.tag == "default":
            _parse_defaults(ctx, child, mine, False)


def _parse_header(ctx: _Ctx, root: ET.Element) -> None:
    base = ctx.path.parent
    meshdir = assetdir = None
    for c in root.findall("compiler"):
        angle = c.get("angle")
        if angle is not None:
            if angle not in ("degree", "radian"):
                raise ctx.error("<compiler>", f"angle must be 'degree' or 'radian', got {angle!r}")
            ctx.angle = 1.0 if angle == "radian" else math.pi / 180
        if c.get("eulerseq") is not None:
            seq = c.get("eulerseq")
            if len(seq) != 3 or any(ch not in "xyzXYZ" for ch in seq):
                raise ctx.error("<compiler>", f"eulerseq must be 3 letters of xyzXYZ, got {seq!r}")
            ctx.eulerseq = seq
        if c.get("autolimits") is not None:
            ctx.autolimits = c.get("autolimits") == "true"
        if c.get("coordinate", "local") != "local":
            raise ctx.error("<compiler>", "coordinate='global' is not supported (removed in MuJoCo 2.3.3)")
        meshdir = c.get("meshdir", meshdir)
        assetdir = c.get("assetdir", assetdir)
    d = meshdir if meshdir is not None else assetdir
    ctx.meshdir = base / d if d is not None else base
    ctx.defaults = {}
    tops = root.findall("default")
    for top in tops:
        _parse_defaults(ctx, top, {}, True)
    ctx.defaults.setdefault("main", {})
    for asset in root.findall("asset"):
        for m in asset.findall("mesh"):
            cls = m.get("class", "main")
            attrs = _resolve(ctx, m, cls)
            name = attrs.get("name") or (Path(attrs["file"]).stem if "file" in attrs else None)
            if name is None:
                raise ctx.error(_where(m), "a mesh needs a name or a file")
            if "file" in attrs:
                f = Path(attrs["file"])
                f = f if f.is_absolute() else ctx.meshdir / f
                if not f.is_file():
                    raise MissingFileError(f"{ctx.path}: <mesh name=\"{name}\">: mesh file not found: {f}")
            ctx.mesh_assets[name] = attrs


def _load_mesh(ctx: _Ctx, name: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) metres and faces (F, 3) of mesh asset ``name`` in the mesh file's frame, scaled."""
    if name in ctx.mesh_cache:
        return ctx.mesh_cache[name]
    if name not in ctx.mesh_assets:
        raise ctx.error(where, f"unknown mesh {name!r}; known meshes: {', '.join(ctx.mesh_assets) or 'none'}")
    attrs = ctx.mesh_assets[name]
    mwhere = f'<mesh name="{name}">'
    if "refpos" in attrs or "refquat" in attrs:
        raise ctx.error(mwhere, "refpos/refquat are not supported")
    import trimesh

    if "file" in attrs:
        f = Path(attrs["file"])
        f = f if f.is_absolute() else ctx.meshdir / f
        if f.suffix.lower() == ".msh":
            raise ctx.error(mwhere, f"MuJoCo's binary .msh format is not supported ({f})")
        try:
            m = trimesh.load(str(f), process=False, force="mesh")
            V, F = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
        except Exception as err:  # trimesh's loaders raise many types; all mean an unreadable file
            raise FileFormatError(f"{ctx.path}: {mwhere}: cannot read mesh file {f}: {err}") from None
    else:
        V = _floats(ctx, attrs, "vertex", mwhere)
        if V is None or len(V) % 3 or len(V) < 12:
            raise ctx.error(mwhere, "needs a file or a vertex list of at least 4 points")
        V = V.reshape(-1, 3)
        Fa = _floats(ctx, attrs, "face", mwhere)
        if Fa is None:
            hull = trimesh.convex.convex_hull(V)
            V, F = np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int64)
        else:
            if len(Fa) % 3 or (Fa != np.round(Fa)).any() or Fa.min() < 0 or Fa.max() >= len(V):
                raise ctx.error(mwhere, "face must list vertex indices in triples")
            F = Fa.reshape(-1, 3).astype(np.int64)
    if len(V) == 0 or len(F) == 0:
        raise ctx.error(mwhere, "the mesh is empty")
    V = V * _floats(ctx, attrs, "scale", mwhere, 3, default=(1.0, 1.0, 1.0))
    # Merge exact duplicates (STL stores three per triangle), keeping first occurrences in their order.
    _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    V, F = V[first[order]], rank[inverse.reshape(-1)][F]
    ctx.mesh_cache[name] = (V, F)
    return V, F


# ----------------------------------------------------------------------------------------------------------------
# The body tree
# ----------------------------------------------------------------------------------------------------------------
@dataclass
class _Tree:
    links: list = field(default_factory=list)  # LinkSpec
    joints: list = field(default_factory=list)  # JointSpec
    geoms: list = field(default_factory=list)  # GeomSpec
    parent: list = field(default_factory=list)  # link index of the parent, -1 for the root
    link_joints: list = field(default_factory=list)  # per link: joint indices


def _add_body(ctx: _Ctx, tree: _Tree, body: ET.Element, parent: int, offset: np.ndarray, cls: str) -> None:
    name = body.get("name") or f"body{len(tree.links)}"
    if any(l.name == name for l in tree.links):
        raise ctx.error(_where(body), "duplicate body name")
    cls = body.get("childclass", cls)
    if cls not in ctx.defaults:
        raise ctx.error(_where(body), f"unknown childclass {cls!r}")
    idx = len(tree.links)
    tree.links.append(LinkSpec(name, tree.links[parent].name if parent >= 0 else None, offset))
    tree.parent.append(parent)
    tree.link_joints.append([])
    _add_children(ctx, tree, body, idx, np.eye(4), cls)


def _add_children(ctx: _Ctx, tree: _Tree, elem: ET.Element, link: int, F: np.ndarray, cls: str) -> None:
    lname = tree.links[link].name
    for ch in elem:
        tag = ch.tag
        if tag == "body":
            _add_body(ctx, tree, ch, link, F @ _frame(ctx, ch.attrib, _where(ch)), cls)
        elif tag == "frame":
            fcls = ch.get("childclass", cls)
            _add_children(ctx, tree, ch, link, F @ _frame(ctx, ch.attrib, _where(ch)), fcls)
        elif tag in ("joint", "freejoint"):
            _add_joint(ctx, tree, ch, link, F, cls)
        elif tag == "geom":
            g = _geom(ctx, ch, lname, F, cls)
            if g is not None:
                tree.geoms.append(g)
        elif tag in _REFUSED_TAGS:
            raise ctx.error(f"{_where(ch)} in body {lname!r}", f"<{tag}> is not supported; expand it first")


def _add_joint(ctx: _Ctx, tree: _Tree, elem: ET.Element, link: int, F: np.ndarray, cls: str) -> None:
    lname = tree.links[link].name
    attrs = {} if elem.tag == "freejoint" else _resolve(ctx, elem, cls)
    jtype = "free" if elem.tag == "freejoint" else attrs.get("type", "hinge")
    name = elem.get("name") or f"{lname}_joint{len(tree.link_joints[link])}"
    where = f'<joint name="{name}"> in body {lname!r}'
    if jtype == "free":
        if link != 0 or tree.link_joints[0]:
            raise ctx.error(where, "a free joint is only supported as the first joint of the root body")
        return
    if jtype not in ("hinge", "slide", "ball"):
        raise ctx.error(where, f"unknown joint type {jtype!r}; expected hinge, slide, ball or free")
    if _floats(ctx, attrs, "ref", where, 1, default=(0.0,))[0] != 0.0:
        raise ctx.error(where, "a non-zero ref is not supported")
    anchor = F[:3, :3] @ _floats(ctx, attrs, "pos", where, 3, default=(0.0, 0.0, 0.0)) + F[:3, 3]
    rng = _floats(ctx, attrs, "range", where, 2)
    limited = {"true": True, "false": False}.get(attrs.get("limited", "auto"), rng is not None)
    if limited and rng is None:
        rng = np.zeros(2)  # MuJoCo's default range
    if jtype == "ball":
        if limited:
            r = abs(rng[1]) * ctx.angle
            limits = np.array([-r, r])
        else:
            limits = np.array(_UNLIMITED["hinge"])
        specs = [JointSpec(f"{name}_{c}", lname, "hinge", F[:3, :3] @ e, anchor, limits)
                 for c, e in zip("xyz", np.eye(3))]
    else:
        axis = _floats(ctx, attrs, "axis", where, 3, default=(0.0, 0.0, 1.0))
        if np.linalg.norm(axis) < 1e-12:
            raise ctx.error(where, "axis is zero")
        if limited:
            limits = rng * (ctx.angle if jtype == "hinge" else 1.0)
            if limits[0] > limits[1]:
                raise ctx.error(where, f"range lower bound exceeds upper bound: {attrs.get('range')!r}")
        else:
            limits = np.array(_UNLIMITED[jtype])
        specs = [JointSpec(name, lname, jtype, F[:3, :3] @ (axis / np.linalg.norm(axis)), anchor, limits)]
    for s in specs:
        if any(j.name == s.name for j in tree.joints):
            raise ctx.error(where, f"duplicate joint name {s.name!r}")
        tree.link_joints[link].append(len(tree.joints))
        tree.joints.append(s)


def _geom(ctx: _Ctx, elem: ET.Element, lname: str, F: np.ndarray, cls: str) -> GeomSpec | None:
    attrs = _resolve(ctx, elem, cls)
    where = f"{_where(elem)} in body {lname!r}"
    try:
        visual = int(attrs.get("contype", "1")) == 0 and int(attrs.get("conaffinity", "1")) == 0
    except ValueError:
        raise ctx.error(where, "contype/conaffinity must be integers") from None
    if visual:
        return None
    gtype = attrs.get("type", "sphere")
    if gtype in ("plane", "hfield", "sdf"):
        raise ctx.error(where, f"geom type {gtype!r} is not supported on a hand")
    if gtype not in GEOM_TYPES and gtype != "ellipsoid":
        raise ctx.error(where, f"unknown geom type {gtype!r}")
    if "mesh" in attrs and gtype != "mesh":
        raise ctx.error(where, f"a {gtype} fitted to mesh {attrs['mesh']!r} is not supported; use type='mesh'")
    size = _floats(ctx, attrs, "size", where, (1, 2, 3), default=(0.0, 0.0, 0.0))
    size = np.concatenate([size, np.zeros(3 - len(size))])
    if "fromto" in attrs and gtype in ("capsule", "cylinder", "box", "ellipsoid"):
        ft = _floats(ctx, attrs, "fromto", where, 6)
        v = ft[:3] - ft[3:]  # MuJoCo's geom z points from "to" to "from"
        if np.linalg.norm(v) < 1e-15:
            raise ctx.error(where, "fromto has zero length")
        pose = _pose(_z_to_vec(v), 0.5 * (ft[:3] + ft[3:]))
        size[1 if gtype in ("capsule", "cylinder") else 2] = 0.5 * np.linalg.norm(v)
    else:
        pose = _frame(ctx, attrs, where)
    pose = F @ pose
    need = {"sphere": 1, "capsule": 2, "cylinder": 2, "box": 3, "ellipsoid": 3, "mesh": 0}[gtype]
    if (size[:need] <= 0).any():
        raise ctx.error(where, f"a {gtype} needs {need} positive size values, got {attrs.get('size')!r}")
    name = attrs.get("name")
    if gtype == "mesh":
        if "mesh" not in attrs:
            raise ctx.error(where, "a mesh geom needs mesh=")
        V, Fc = _load_mesh(ctx, attrs["mesh"], where)
        return GeomSpec(lname, "mesh", np.zeros(3), pose, (V, Fc), name)
    if gtype == "ellipsoid":
        import trimesh

        s = trimesh.creation.icosphere(subdivisions=3)
        return GeomSpec(lname, "mesh", np.zeros(3), pose, (np.asarray(s.vertices) * size, np.asarray(s.faces)), name)
    return GeomSpec(lname, gtype, size[: max(need, 1)] if gtype != "box" else size, pose, None, name)


# ----------------------------------------------------------------------------------------------------------------
# Fingers
# ----------------------------------------------------------------------------------------------------------------
def _support(g: GeomSpec, d: np.ndarray) -> tuple[float, np.ndarray]:
    """Support value and point (link frame) of geom ``g`` along unit ``d`` (link frame)."""
    R, t = g.pose[:3, :3], g.pose[:3, 3]
    dl = R.T @ d
    dl = np.where(np.abs(dl) < 1e-9, 0.0, dl)
    s = np.resize(np.asarray(g.size, dtype=np.float64), 3)
    if g.type == "mesh":
        V = g.mesh[0]
        k = np.flatnonzero(V @ dl >= (V @ dl).max() - 1e-12)
        p = V[k].mean(0)
    elif g.type == "sphere":
        p = s[0] * dl
    elif g.type == "capsule":
        p = np.array([0.0, 0.0, s[1] * np.sign(dl[2])]) + s[0] * dl
    elif g.type == "cylinder":
        rad = np.array([dl[0], dl[1], 0.0])
        n = np.linalg.norm(rad)
        p = (s[0] * rad / n if n > 0 else np.zeros(3)) + np.array([0.0, 0.0, s[1] * np.sign(dl[2])])
    else:  # box
        p = s * np.sign(dl)
    pw = R @ p + t
    return float(pw @ d), pw


def _detect_fingers(tree: _Tree) -> tuple[list[FingerSpec], float]:
    L = len(tree.links)
    X = [np.eye(4)] * L  # link poses at q = 0 relative to the root
    children = [[] for _ in range(L)]
    for l in range(1, L):
        X[l] = X[tree.parent[l]] @ tree.links[l].offset
        children[tree.parent[l]].append(l)
    jlink = {d: l for l in range(L) for d in tree.link_joints[l]}
    fingers, length, used = [], 0.0, set()
    for leaf in range(1, L):
        if children[leaf]:
            continue
        chain = [leaf]
        while tree.parent[chain[-1]] > 0 and len(children[tree.parent[chain[-1]]]) < 2:
            chain.append(tree.parent[chain[-1]])
        chain.reverse()
        branch = tree.parent[chain[0]]
        hinges = [d for l in chain for d in tree.link_joints[l] if tree.joints[d].type == "hinge"]
        if len(hinges) < 2:
            continue
        links = [l for l in chain if tree.link_joints[l]] + ([] if tree.link_joints[leaf] else [leaf])
        links = links[-4:]
        Rl = X[leaf][:3, :3]

        def axis_leaf(d):
            return Rl.T @ X[jlink[d]][:3, :3] @ tree.joints[d].axis / np.linalg.norm(tree.joints[d].axis)

        a_last = axis_leaf(hinges[-1])
        flex = [d for d in hinges if abs(axis_leaf(d) @ a_last) > _FLEX_PARALLEL_COS][-3:]
        # Finger direction: from the nearest ancestor origin that differs from the leaf's.
        d_vec, anc = np.array([0.0, 0.0, 1.0]), tree.parent[leaf]
        while anc >= 0:
            v = X[leaf][:3, 3] - X[anc][:3, 3]
            if np.linalg.norm(v) > 1e-6:
                d_vec = Rl.T @ v / np.linalg.norm(v)
                break
            anc = tree.parent[anc]
        # Tip: support point of the distal geometry (or of the nearest finger link with geometry).
        tip = np.zeros(3)
        for l in reversed(links):
            gs = [g for g in tree.geoms if g.link == tree.links[l].name]
            if gs:
                Tl = np.linalg.inv(X[leaf]) @ X[l]
                moved = [GeomSpec(g.link, g.type, g.size, Tl @ g.pose, g.mesh) for g in gs]
                tip = max((_support(g, d_vec) for g in moved), key=lambda sp: sp[0])[1]
                break
        lo, hi = tree.joints[flex[-1]].limits
        nail = np.cross(d_vec, axis_leaf(flex[-1])) * (1.0 if hi + lo >= 0 else -1.0)
        nail = nail - d_vec * (nail @ d_vec)
        if np.linalg.norm(nail) < 1e-9:  # flexion axis along the finger: any perpendicular
            nail = np.cross(d_vec, [1.0, 0.0, 0.0] if abs(d_vec[0]) < 0.9 else [0.0, 1.0, 0.0])
        names = [tree.links[l].name for l in links]
        prefix = os.path.commonprefix(names)
        fname = re.sub(r"^(rh|lh|right|left)_", "", prefix).strip("_")
        if not fname or fname in used:
            fname = tree.links[leaf].name
        used.add(fname)
        fingers.append(FingerSpec(fname, tuple(names), nail / np.linalg.norm(nail), tip,
                                  tuple(tree.joints[d].name for d in flex)))
        tip_root = X[leaf][:3, :3] @ tip + X[leaf][:3, 3]
        length = max(length, float(np.linalg.norm(tip_root - X[branch][:3, 3])))
    return fingers, length


def _detect_side(path: Path, model: str, links: list) -> str:
    for text in (path.stem, model):
        m = re.search(r"(?:^|[^a-z])(right|left)(?:[^a-z]|$)", text.lower())
        if m:
            return m.group(1)
    prefixes = {l.name[:3].lower() for l in links}
    if "rh_" in prefixes and "lh_" not in prefixes:
        return "right"
    if "lh_" in prefixes and "rh_" not in prefixes:
        return "left"
    return "none"


def _custom_annotations(ctx: _Ctx, root: ET.Element) -> dict | None:
    """Annotations written by :func:`hand_to_mjcf` in ``<custom>``, or None when the file has none."""
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
    return {"side": texts["torchhand_side"], "length": float(nums.get("torchhand_length", [0.0])[0]),
            "q_rest": nums.get("torchhand_q_rest"), "fingers": fingers}


# ----------------------------------------------------------------------------------------------------------------
# Public API: import
# ----------------------------------------------------------------------------------------------------------------
def load_mjcf(path, *, root_body: str | None = None, side: str | None = None, name: str | None = None) -> HandModel:
    """Load a hand from an MJCF file (see the module docstring for what is supported and the heuristics).

    path:      the .xml file; mesh files are found through ``<compiler meshdir/assetdir>`` relative to it
    root_body: name of the body that becomes link 0 (default: the first body under ``<worldbody>``); its world pose
               (before its own joints) is the FK's ``root`` input
    side:      "right" | "left" | "none"; default: from the file name, model name or body-name prefixes
    name:      model name; default: ``<mujoco model=...>`` or the file name
    returns: HandModel (float64, CPU); joints in MuJoCo's qpos order (free joint excluded)
    raises: MissingFileError (file or mesh file missing), FileFormatError (malformed XML, unsupported or invalid
            element, naming the file and the element), UnknownNameError (``root_body`` not found)
    """
    if side is not None and side not in ("right", "left", "none"):
        raise InputValueError(f"side: expected 'right', 'left' or 'none', got {side!r}")
    path = Path(path)
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
    worlds = xml_root.findall("worldbody")  # MuJoCo merges repeated sections
    bodies = [b for w in worlds for b in w.findall("body")]
    if not bodies:
        raise ctx.error("<worldbody>", "no body found")

    # Find the root body and the childclass in force there.
    def find(elem, cls):
        for b in elem:
            if b.tag not in ("body", "frame"):
                continue
            bcls = b.get("childclass", cls)
            if b.tag == "body" and b.get("name") == root_body:
                return b, cls
            hit = find(b, bcls)
            if hit is not None:
                return hit
        return None

    if root_body is not None:
        hit = next((h for h in (find(w, "main") for w in worlds) if h is not None), None)
        if hit is None:
            known = [b.get("name") for w in worlds for b in w.iter("body") if b.get("name")]
            raise UnknownNameError(f"{path}: root_body {root_body!r} not found; bodies: {', '.join(known)}")
        rb, cls = hit
    else:
        rb, cls = bodies[0], "main"
        inner = rb.findall("body")
        if rb.get("name") == _ROOT_WRAPPER and len(inner) == 1:
            cls, rb = rb.get("childclass", cls), inner[0]
    tree = _Tree()
    _add_body(ctx, tree, rb, -1, np.eye(4), cls)

    stored = _custom_annotations(ctx, xml_root)
    if stored is not None:
        fingers, length = stored["fingers"], stored["length"]
        side = side or stored["side"]
        q_rest = stored["q_rest"]
        if q_rest is not None and len(q_rest) != len(tree.joints):
            raise ctx.error('<numeric name="torchhand_q_rest">', f"expected {len(tree.joints)} values")
    else:
        fingers, length = _detect_fingers(tree)
        q_rest = None
    model_name = xml_root.get("model") or path.stem
    side = side or _detect_side(path, model_name, tree.links)
    return build_hand_model(name or model_name, tree.links, tree.joints, tree.geoms, fingers, side=side,
                            length=length, q_rest=q_rest)


# ----------------------------------------------------------------------------------------------------------------
# Public API: export
# ----------------------------------------------------------------------------------------------------------------
def _fmt(a) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(a, dtype=np.float64).reshape(-1))


def _set_pose(e: ET.Element, T: np.ndarray) -> None:
    if np.any(T[:3, 3] != 0):
        e.set("pos", _fmt(T[:3, 3]))
    if np.any(T[:3, :3] != np.eye(3)):
        e.set("quat", _fmt(_mat_to_quat(T[:3, :3])))


def hand_to_mjcf(hand: HandModel) -> str:
    """The hand as a self-contained MJCF string that MuJoCo loads (see the module docstring).

    hand: any HandModel (any device or dtype; written from float64 CPU copies)
    returns: XML text; MuJoCo's qpos = (root position (3), root quaternion wxyz (4), q (D)) gives body poses equal to
        ``hand.forward_kinematics(q, root)``; nq = 7 + D
    raises: InputValueError for a mesh MuJoCo cannot compile (fewer than 4 vertices or flat)
    """
    h = hand.to(device="cpu", dtype=torch.float64)
    ch, gm = h.chain, h.geoms
    L, D = h.num_links, h.num_joints
    root = ET.Element("mujoco", model=h.name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")

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

    world = ET.SubElement(root, "worldbody")
    children = [[] for _ in range(L)]
    for l in range(1, L):
        children[int(ch.link_parent[l])].append(l)
    offsets = ch.link_offset.numpy()
    geoms_of = [[] for _ in range(L)]
    for g in range(gm.link.shape[0]):
        geoms_of[int(gm.link[g])].append(g)

    def body(parent_elem: ET.Element, l: int, with_free: bool) -> None:
        b = ET.SubElement(parent_elem, "body", name=h.link_names[l])
        if l:
            _set_pose(b, offsets[l])
        ET.SubElement(b, "inertial", pos="0 0 0", mass="0.001", diaginertia="1e-07 1e-07 1e-07")
        if with_free:
            ET.SubElement(b, "freejoint", name="root")
        for d in ch.link_joints[l].tolist():
            if d >= D:
                continue
            hinge = int(ch.joint_type[d]) == 0
            j = ET.SubElement(b, "joint", name=h.joint_names[d], type="hinge" if hinge else "slide")
            if hinge and np.any(ch.joint_anchor[d].numpy() != 0):
                j.set("pos", _fmt(ch.joint_anchor[d]))
            j.set("axis", _fmt(ch.joint_axis[d]))
            j.set("limited", "true")
            j.set("range", _fmt(h.joint_limits[d]))
        for n, g in enumerate(geoms_of[l]):
            gtype = GEOM_TYPES[int(gm.type[g])]
            e = ET.SubElement(b, "geom", name=f"{h.link_names[l]}_geom{n}", type=gtype)
            if gtype == "mesh":
                e.set("mesh", mesh_names[g])
            else:
                e.set("size", _fmt(gm.size[g][: {"sphere": 1, "capsule": 2, "cylinder": 2, "box": 3}[gtype]]))
            _set_pose(e, gm.pose[g].numpy())
        for c in children[l]:
            body(b, c, False)

    root_has_joints = bool((ch.link_joints[0] < D).any()) if D else False
    if root_has_joints:
        wrapper = ET.SubElement(world, "body", name=_ROOT_WRAPPER)
        ET.SubElement(wrapper, "inertial", pos="0 0 0", mass="0.001", diaginertia="1e-07 1e-07 1e-07")
        ET.SubElement(wrapper, "freejoint", name="root")
        body(wrapper, 0, False)
    else:
        body(world, 0, True)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


def save_mjcf(hand: HandModel, path) -> Path:
    """Write :func:`hand_to_mjcf` to ``path`` atomically (a temporary file in the same folder, then os.replace).

    returns: the path written; raises MissingFileError when the folder does not exist
    """
    path = Path(path)
    text = hand_to_mjcf(hand)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise MissingFileError(f"path: folder not found: {folder}")
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
