"""MJCF import: :func:`load_mjcf` (facade and full description: :mod:`torchhand.hand.mjcf`).

Parsing (``<compiler>``, ``<default>`` classes, every MJCF orientation form, mesh assets) and the body tree; the
finger and side heuristics are in :mod:`torchhand.hand._mjcf_fingers`.
Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputValueError, MissingFileError, UnknownNameError
from . import dynamics as _dyn
from ._mjcf_common import _ROOT_WRAPPER, _axis_angle, _pose, _quat_to_mat, _z_to_vec
from ._mjcf_fingers import _detect_fingers, _detect_side
from .model import (GEOM_TYPES, FingerSpec, GeomSpec, HandModel, InertialSpec, JointSpec, LinkSpec,
                    build_hand_model)

__all__ = ["load_mjcf"]

_UNLIMITED = {"hinge": (-math.pi, math.pi), "slide": (-1.0, 1.0)}  # radians, metres
_REFUSED_TAGS = ("include", "replicate", "attach", "composite", "flexcomp")


# ----------------------------------------------------------------------------------------------------------------
# Parsing context and attribute helpers
# ----------------------------------------------------------------------------------------------------------------
@dataclass
class _Ctx:
    path: Path
    angle: float = math.pi / 180  # MuJoCo's default unit is the degree
    eulerseq: str = "xyz"
    autolimits: bool = True
    inertiafromgeom: str = "auto"  # "true" | "false" | "auto"
    inertiagrouprange: tuple = (0, 5)
    boundmass: float = 0.0
    boundinertia: float = 0.0
    balanceinertia: bool = False
    settotalmass: float = -1.0
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
        _parse_inertia_settings(ctx, c)
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


def _parse_inertia_settings(ctx: _Ctx, c: ET.Element) -> None:
    """``<compiler>``'s inertiafromgeom, inertiagrouprange, boundmass, boundinertia, balanceinertia, settotalmass."""
    v = c.get("inertiafromgeom")
    if v is not None:
        if v not in ("true", "false", "auto"):
            raise ctx.error("<compiler>", f"inertiafromgeom must be 'true', 'false' or 'auto', got {v!r}")
        ctx.inertiafromgeom = v
    if c.get("inertiagrouprange") is not None:
        r = _floats(ctx, c.attrib, "inertiagrouprange", "<compiler>", 2)
        ctx.inertiagrouprange = (int(r[0]), int(r[1]))
    for key in ("boundmass", "boundinertia", "settotalmass"):
        if c.get(key) is not None:
            setattr(ctx, key, float(_floats(ctx, c.attrib, key, "<compiler>", 1)[0]))
    if c.get("balanceinertia") is not None:
        ctx.balanceinertia = c.get("balanceinertia") == "true"


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


def _custom_annotations(ctx: _Ctx, root: ET.Element) -> dict | None:
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
    return {"side": texts["torchhand_side"], "length": float(nums.get("torchhand_length", [0.0])[0]),
            "q_rest": nums.get("torchhand_q_rest"), "fingers": fingers}


# ----------------------------------------------------------------------------------------------------------------
# Public API: import
# ----------------------------------------------------------------------------------------------------------------
def load_mjcf(path, *, root_body: str | None = None, side: str | None = None, name: str | None = None) -> HandModel:
    """Load a hand from an MJCF file (see :mod:`torchhand.hand.mjcf` for what is supported and the heuristics).

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

    root_offset = np.eye(4)
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
            # the wrapper carries the free joint (the FK root); the root link's pose in it is its offset
            cls, rb = rb.get("childclass", cls), inner[0]
            root_offset = _frame(ctx, rb.attrib, _where(rb))
    tree = _Tree()
    _add_body(ctx, tree, rb, -1, root_offset, cls)

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
    inertials = tree.inertials
    if ctx.settotalmass > 0:  # MuJoCo's mj_setTotalmass over the hand's bodies
        total = sum(m for m, _, _ in inertials)
        k = ctx.settotalmass / total if total > 0 else 0.0
        inertials = [(m * k, c, I * k) for m, c, I in inertials] if k > 0 else inertials
    specs = [InertialSpec(l.name, m, c, I) for l, (m, c, I) in zip(tree.links, inertials)]
    return build_hand_model(name or model_name, tree.links, tree.joints, tree.geoms, fingers, side=side,
                            length=length, q_rest=q_rest, inertials=specs)
