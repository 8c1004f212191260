"""MJCF body tree for the reader (:func:`torchhand.hand.mjcf.load_mjcf`): bodies become links, joints become
hinge and slide joints, geoms collision geometry, and each body's inertial is read or computed from its geoms.

Produces the plain specs of :mod:`torchhand.hand._specs` in a :class:`_Tree`; attributes and defaults are parsed by
:mod:`torchhand.hand._mjcf_parse`. Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see
:mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from . import dynamics as _dyn
from ._mjcf_common import _pose, _z_to_vec
from ._mjcf_parse import _REFUSED_TAGS, _Ctx, _floats, _frame, _load_mesh, _resolve, _where
from ._specs import GEOM_TYPES, GeomSpec, JointSpec, LinkSpec

_UNLIMITED = {"hinge": (-math.pi, math.pi), "slide": (-1.0, 1.0)}  # radians, metres


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
    inertials: list = field(default_factory=list)  # per link: (mass, com (3,), inertia (3, 3)), link frame
    from_geoms: list = field(default_factory=list)  # per link: None (explicit inertial) or a list of geom inertials


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
    found = body.findall("inertial")
    if len(found) > 1:
        raise ctx.error(_where(body), "more than one <inertial>")
    explicit = _inertial(ctx, found[0], name) if found else None
    # MuJoCo: from the geoms when inertiafromgeom is true, or auto without an explicit <inertial>.
    by_geoms = ctx.inertiafromgeom == "true" or (ctx.inertiafromgeom == "auto" and explicit is None)
    tree.from_geoms.append([] if by_geoms else None)
    tree.inertials.append(None)
    _add_children(ctx, tree, body, idx, np.eye(4), cls)
    if by_geoms:
        inertial = _dyn.combine_inertials(tree.from_geoms[idx])
    else:
        inertial = explicit if explicit is not None else (0.0, np.zeros(3), np.zeros((3, 3)))
    tree.inertials[idx] = _bound_inertial(ctx, inertial, name)


def _inertial(ctx: _Ctx, elem: ET.Element, lname: str):
    """An ``<inertial>``: (mass, com (3,), inertia (3, 3) about com in the body frame); I = R diag R^T for
    ``diaginertia`` in the inertial frame's orientation R, or ``fullinertia`` (ixx iyy izz ixy ixz iyz)."""
    attrs = dict(elem.attrib)
    where = f"<inertial> in body {lname!r}"
    for key in ("pos", "mass"):
        if key not in attrs:
            raise ctx.error(where, f"attribute {key} is required")
    mass = float(_floats(ctx, attrs, "mass", where, 1)[0])
    if mass < 0:
        raise ctx.error(where, f"mass must be >= 0, got {mass}")
    if "fullinertia" in attrs:
        orient = [k for k in ("quat", "axisangle", "xyaxes", "zaxis", "euler") if k in attrs]
        if orient:
            raise ctx.error(where, f"fullinertia and an orientation ({', '.join(orient)}) cannot both be given")
        v = _floats(ctx, attrs, "fullinertia", where, 6)
        T = _frame(ctx, attrs, where)
        inertia = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    elif "diaginertia" in attrs:
        T = _frame(ctx, attrs, where)
        R = T[:3, :3]
        inertia = R @ np.diag(_floats(ctx, attrs, "diaginertia", where, 3)) @ R.T
    else:
        raise ctx.error(where, "needs diaginertia or fullinertia")
    return mass, T[:3, 3], 0.5 * (inertia + inertia.T)


def _bound_inertial(ctx: _Ctx, inertial, lname: str):
    """MuJoCo's per-body corrections: boundmass, boundinertia (on the principal moments), then the triangle
    inequality A + B >= C of the principal moments (balanceinertia replaces them by their mean, else an error)."""
    mass, com, inertia = inertial
    mass = max(mass, ctx.boundmass)
    eig, vec = np.linalg.eigh(inertia)
    if ctx.boundinertia > 0 and (eig < ctx.boundinertia).any():
        eig = np.maximum(eig, ctx.boundinertia)
        inertia = vec @ np.diag(eig) @ vec.T
    if eig[0] + eig[1] < eig[2] * (1 - 1e-9):
        if not ctx.balanceinertia:
            raise ctx.error(f'<body name="{lname}">', "inertia must satisfy A + B >= C (MuJoCo's "
                                                     "compiler balanceinertia='true' fixes it)")
        inertia = np.eye(3) * eig.mean()
    return mass, com, inertia


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
            g, inertial = _geom(ctx, ch, lname, F, cls, tree.from_geoms[link] is not None)
            if g is not None:
                tree.geoms.append(g)
            if inertial is not None:
                tree.from_geoms[link].append(inertial)
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


def _geom(ctx: _Ctx, elem: ET.Element, lname: str, F: np.ndarray, cls: str, inertia: bool):
    """(collision GeomSpec or None, inertial (mass, com, inertia) in the body frame or None).

    The inertial is computed when ``inertia`` (the body's mass comes from its geoms) and the geom's group is in
    the compiler's inertiagrouprange; visual geoms count too, as in MuJoCo.
    """
    attrs = _resolve(ctx, elem, cls)
    where = f"{_where(elem)} in body {lname!r}"
    try:
        visual = int(attrs.get("contype", "1")) == 0 and int(attrs.get("conaffinity", "1")) == 0
        group = int(attrs.get("group", "0"))
    except ValueError:
        raise ctx.error(where, "contype/conaffinity/group must be integers") from None
    inertia = inertia and ctx.inertiagrouprange[0] <= group <= ctx.inertiagrouprange[1]
    if visual and not inertia:
        return None, None
    gtype = attrs.get("type", "sphere")
    if gtype == "plane" and visual:
        return None, None  # MuJoCo gives planes no volume
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
    mesh = None
    if gtype == "mesh":
        if "mesh" not in attrs:
            raise ctx.error(where, "a mesh geom needs mesh=")
        mesh = _load_mesh(ctx, attrs["mesh"], where)
        spec = GeomSpec(lname, "mesh", np.zeros(3), pose, mesh, name)
    elif gtype == "ellipsoid":
        import trimesh

        s = trimesh.creation.icosphere(subdivisions=3)
        spec = GeomSpec(lname, "mesh", np.zeros(3), pose, (np.asarray(s.vertices) * size, np.asarray(s.faces)), name)
    else:
        spec = GeomSpec(lname, gtype, size[: max(need, 1)] if gtype != "box" else size, pose, None, name)
    inertial = _geom_inertial(ctx, attrs, gtype, size, pose, mesh, where) if inertia else None
    return (None if visual else spec), inertial


def _geom_inertial(ctx: _Ctx, attrs: dict, gtype: str, size, pose, mesh, where: str):
    """MuJoCo's geom inertia (volume type): ``mass`` if given, else ``density`` (default 1000 kg/m^3) times the
    volume; meshes by their asset's ``inertia`` mode (MuJoCo's default "legacy", "exact", "convex"), with MuJoCo's
    float32 rounding of vertices."""
    if attrs.get("shellinertia", "false") == "true":
        raise ctx.error(where, "shellinertia is not supported")
    mass = float(_floats(ctx, attrs, "mass", where, 1)[0]) if "mass" in attrs else None
    density = float(_floats(ctx, attrs, "density", where, 1, default=(_dyn.DEFAULT_DENSITY,))[0])
    if gtype == "mesh":
        mode = ctx.mesh_assets[attrs["mesh"]].get("inertia", "legacy")
        if mode not in ("legacy", "exact", "convex"):
            raise ctx.error(f'<mesh name="{attrs["mesh"]}">', f"mesh inertia {mode!r} is not supported; "
                                                              "expected legacy, exact or convex")
        local = _dyn.mesh_inertial(mesh[0], mesh[1], density, mass, mode, float32=True)  # MuJoCo's float32 vertices
    else:
        local = _dyn.primitive_inertial(gtype, size, density, mass)
    return _dyn.transform_inertial(local, pose)
