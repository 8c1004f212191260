"""MJCF parsing for the reader (:func:`torchhand.hand.mjcf.load_mjcf`): the parsing context, attributes and
orientations, ``<compiler>`` settings, ``<default>`` classes and mesh assets.

The body tree is read by :mod:`torchhand.hand._mjcf_bodies`, the whole file by :mod:`torchhand.hand._mjcf_read`.
Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, MissingFileError
from ._mjcf_common import _axis_angle, _pose, _quat_to_mat, _z_to_vec

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
