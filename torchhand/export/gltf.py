"""One solution of a result directory as a glTF 2.0 binary file (``.glb``) for Blender, game engines and three.js.

:func:`solution_glb` returns the bytes, :func:`write_solution_glb` writes them atomically. The file holds one scene,
one binary buffer and one animation named ``solution_XXX`` (XXX = the solution index, three digits) whose keyframes
are at ``t / fps`` seconds, ``t = 0 .. T-1`` (one float32 time accessor shared by every channel).

Scene graph (the node names are the interface: readers look nodes up by name)

    ``world``                  the root. Its rotation, -90 degrees about x, turns torchhand's z-up world into glTF's
                               y-up: ``(x, y, z)`` torchhand -> ``(x, z, -y)`` glTF. Everything below it is in
                               torchhand world coordinates, metres (Blender's importer turns y-up back into z-up, so
                               world positions read in Blender are torchhand's).
    ``object``                 child of world: the object mesh (object frame, flat-shaded), animated translation and
                               rotation = ``object_pose``.
    ``table``                  child of world, only when the scene has a table: a static box 2 cm thick, top face at
                               ``table_height``, covering the xy box of the object and wrist positions padded by
                               0.3 m; for a table with an edge (``table_extent``), its block over that rectangle down
                               to the floor (or 2 cm thick without one).
    ``floor``                  child of world, only when the scene has a floor: a static box 2 cm thick, top face at
                               ``floor_height``, under the object, the wrists and the table.
    ``<side>_hand``            child of world at the identity, per hand (``right_hand``, ``left_hand``).
    ``<side>/<link>``          one node per link of the hand model (``right/palm``, ``right/index_distal``), child of
                               its ``link_parent``'s node, the root link's node child of ``<side>_hand``. Animated
                               translation and rotation: the root link's world pose, the other links' local pose
                               ``inv(T_parent) @ T_link`` (LINEAR). Mesh: the link's collision geoms merged, in the
                               link frame (links without geoms have none). A link whose name would be a tip node's
                               (the Allegro hand's link ``ff_tip``) is ``<side>/<link>_link`` (:func:`link_node_names`).
    ``<side>/<finger>_tip``    child of the finger's distal link node at the fixed translation ``fingertip[f]``, the
                               pad point (no mesh, not animated): its world position is the fingertip's.
    ``contact_<k>``            with ``contacts=True``, child of world, one per hand-object contact slot k: a sphere of
                               radius ``contact_radius`` (metres), translation = ``contact_point[t, k]`` (held at the
                               last active point while inactive), scale 1 where ``contact_mask[t, k]`` else 0 (STEP).

Rotations are unit quaternions, xyzw, float32, sign-continuous along time. ``scene.extras`` holds
``{"fps", "frames", "solution"}``; ``asset.generator`` is ``"torchhand export"``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pygltflib as gl
import torch
import trimesh

from .._atomic import atomic_bytes
from ..errors import InputTypeError, InputValueError
from ..hand._link_geometry import link_geom_meshes
from ..hand.model import GEOM_TYPES

__all__ = ["Y_UP_ROTATION", "COLORS", "solution_glb", "write_solution_glb", "link_node_names"]

Y_UP_ROTATION = (-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))
"""Rotation of the ``world`` node, xyzw: -90 degrees about x, ``(x, y, z)`` torchhand -> ``(x, z, -y)`` glTF."""

COLORS = {"hand": (0.87, 0.67, 0.55, 1.0), "object": (0.25, 0.45, 0.85, 1.0), "table": (0.6, 0.6, 0.6, 1.0),
          "contact": (0.9, 0.1, 0.1, 1.0)}
"""Base colours (linear RGBA) of the materials."""

TABLE_PAD = 0.3         # metres around the object's and wrists' xy footprint
TABLE_THICKNESS = 0.02  # metres
_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4"}


def solution_glb(result, index: int, *, contacts: bool = False, contact_radius: float = 0.004) -> bytes:
    """The .glb bytes of solution ``index`` of ``result`` (a :class:`torchhand.io.result.Result`).

    index: solution position in ``result.solution_files``, 0 .. len - 1
    contacts: also write one sphere node ``contact_<k>`` per hand-object contact slot
    contact_radius: radius of the contact spheres, metres, > 0
    Raises InputTypeError / InputValueError naming ``index`` or ``contact_radius``.
    """
    n = len(result.solution_files)
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
        raise InputTypeError(f"index: expected an int, got {type(index).__name__}")
    if not 0 <= index < n:
        raise InputValueError(f"index: solution {int(index)} out of range; {result.path} has {n} solutions"
                              + (f" (0..{n - 1})" if n else ""))
    if not (isinstance(contact_radius, (int, float)) and math.isfinite(contact_radius) and contact_radius > 0):
        raise InputValueError(f"contact_radius: expected a finite number > 0 (metres), got {contact_radius!r}")
    index = int(index)
    sol = result.solution(index)
    number = sol.index if sol.index >= 0 else index            # XXX of sol_XXX.npz
    scene = result.scene
    T, fps = sol.T, float(sol.fps)

    w = _Writer()
    w.g.scene = 0
    w.g.scenes = [gl.Scene(name="scene", nodes=[0], extras={"fps": fps, "frames": T, "solution": number})]
    world = w.node("world", None, rotation=list(Y_UP_ROTATION))
    w.time = w.accessor((np.arange(T) / fps).astype(np.float32)[:, None], bounds=True)
    w.anim = gl.Animation(name=f"solution_{number:03d}")
    w.g.animations = [w.anim]

    obj = w.node("object", world, mesh=w.mesh("object", *_flat(np.asarray(scene.object.mesh.vertices),
                                                               np.asarray(scene.object.mesh.faces)), "object"))
    w.animate(obj, sol.object_pose[:, None])

    env = scene.environment
    if env.table or env.floor:
        xy = np.concatenate([sol.object_pose[:, :2, 3]] + [h.root_pose[:, :2, 3] for h in sol.hands])
        lo, hi = xy.min(0) - TABLE_PAD, xy.max(0) + TABLE_PAD
        for name, bounds in _environment_boxes(env, lo, hi):
            box = trimesh.creation.box(bounds=bounds)
            w.node(name, world, mesh=w.mesh(name, *_flat(box.vertices, box.faces), "table"))

    for hs in sol.hands:
        _hand(w, world, result.hand_models[hs.side], hs)

    if contacts:
        _contacts(w, world, sol.contact_mask, sol.contact_point, contact_radius)

    blob = bytes(w.blob) + b"\0" * (-len(w.blob) % 4)
    w.g.buffers = [gl.Buffer(byteLength=len(blob))]
    w.g.set_binary_blob(blob)
    return b"".join(w.g.save_to_bytes())


def _environment_boxes(env, lo: np.ndarray, hi: np.ndarray) -> list:
    """(name, bounds (2, 3)) of the boxes that show the environment: a table top over ``lo``-``hi`` (x, y) under an
    unbounded table plane, the table block over its rectangle down to the floor (or a top ``TABLE_THICKNESS``
    thick) for a table with an edge, and a floor slab over ``lo``-``hi`` and the table."""
    out = []
    if env.table:
        top = float(env.table_height)
        if env.table_extent is None:
            out.append(("table", [[lo[0], lo[1], top - TABLE_THICKNESS], [hi[0], hi[1], top]]))
        else:
            x0, x1, y0, y1 = env.table_extent
            bottom = float(env.floor_height) if env.floor else top - TABLE_THICKNESS
            out.append(("table", [[x0, y0, bottom], [x1, y1, top]]))
            lo, hi = np.minimum(lo, [x0, y0]), np.maximum(hi, [x1, y1])
    if env.floor:
        f = float(env.floor_height)
        out.append(("floor", [[lo[0], lo[1], f - TABLE_THICKNESS], [hi[0], hi[1], f]]))
    return out


def write_solution_glb(result, index: int, path, *, contacts: bool = False) -> Path:
    """Write :func:`solution_glb` of solution ``index`` to ``path`` atomically (parent folders are created);
    returns the path."""
    data = solution_glb(result, index, contacts=contacts)
    path = Path(path)
    atomic_bytes(path, data)
    return path


def link_node_names(model, side: str) -> list[str]:
    """Node name of each link of ``model`` (L,): ``<side>/<link>``, with ``_link`` appended where that name is a
    fingertip node's ``<side>/<finger>_tip`` (the Allegro hand's link ``ff_tip`` and finger ``ff``)."""
    taken = {f"{side}/{f}_tip" for f in model.finger_names}
    out = []
    for name in model.link_names:
        node = f"{side}/{name}"
        while node in taken:
            node += "_link"
        taken.add(node)
        out.append(node)
    return out


# ---------------------------------------------------------------------------------------------------------------
# The parts of the scene


def _hand(w: "_Writer", world: int, model, hs) -> None:
    """Nodes of one hand: the group node, one animated node per link with its geoms, one tip node per finger."""
    side = hs.side
    if model.dtype != torch.float64:
        model = model.to(dtype=torch.float64)
    with torch.no_grad():
        Tw = model.forward_kinematics(torch.as_tensor(hs.q, dtype=torch.float64).cpu(),
                                      torch.as_tensor(hs.root_pose, dtype=torch.float64).cpu()).numpy()  # (T, L, 4, 4)
    parent = model.chain.link_parent.cpu().numpy()
    local = Tw.copy()
    child = parent >= 0
    local[:, child] = _rigid_inv(Tw[:, parent[child]]) @ Tw[:, child]

    meshes = _link_meshes(model)
    group = w.node(f"{side}_hand", world)
    names = link_node_names(model, side)
    nodes = [w.node(name, None, mesh=w.mesh(name, *meshes[l], "hand") if l in meshes else None)
             for l, name in enumerate(names)]
    for l, p in enumerate(parent.tolist()):
        w.g.nodes[group if p < 0 else nodes[p]].children.append(nodes[l])
    w.animate(nodes, local)
    tip = model.fingertip.detach().cpu().double().numpy()
    for f, (name, d) in enumerate(zip(model.finger_names, model.distal_link.tolist())):
        w.node(f"{side}/{name}_tip", nodes[d], translation=tip[f].tolist())


def _contacts(w: "_Writer", world: int, mask: np.ndarray, point: np.ndarray, radius: float) -> None:
    """One sphere node per contact slot: translation held at the last active point, scale 0/1 (STEP)."""
    T, K = mask.shape
    if K == 0:
        return
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    mesh = w.mesh("contact", sphere.vertices, sphere.vertex_normals, sphere.faces, "contact")
    t = np.arange(T)[:, None]
    last = np.maximum.accumulate(np.where(mask, t, -1), axis=0)             # (T, K) last active frame, -1 before
    first = np.where(mask.any(0), mask.argmax(0), 0)                        # (K,) first active frame
    src = np.where(last >= 0, last, first[None, :])
    pos = np.take_along_axis(point, src[..., None], axis=0)                 # (T, K, 3)
    scale = np.repeat(mask.astype(np.float32)[..., None], 3, axis=-1)       # (T, K, 3)
    for k in range(K):
        node = w.node(f"contact_{k}", world, mesh=mesh, translation=pos[0, k].tolist(), scale=scale[0, k].tolist())
        w.channel(node, "translation", pos[:, k])
        w.channel(node, "scale", scale[:, k], "STEP")


def _link_meshes(model) -> dict:
    """link index -> (vertices (V, 3), normals (V, 3), faces (F, 3)) of the link's geoms merged, link frame:
    capsules and spheres smooth-shaded, boxes, cylinders and meshes flat."""
    kinds = [GEOM_TYPES[i] for i in model.geoms.type.tolist()]
    per_link: dict = {}
    for i, link in enumerate(model.geoms.link.tolist()):
        per_link.setdefault(link, []).append(kinds[i])
    out = {}
    for link, meshes in link_geom_meshes(model, sections=12).items():
        parts = []
        for kind, m in zip(per_link[link], meshes):
            if kind in ("capsule", "sphere"):
                parts.append((np.asarray(m.vertices), np.asarray(m.vertex_normals), np.asarray(m.faces)))
            else:
                parts.append(_flat(m.vertices, m.faces))
        offsets = np.cumsum([0] + [len(v) for v, _, _ in parts[:-1]])
        out[link] = (np.concatenate([v for v, _, _ in parts]), np.concatenate([n for _, n, _ in parts]),
                     np.concatenate([f + o for (_, _, f), o in zip(parts, offsets)]))
    return out


# ---------------------------------------------------------------------------------------------------------------
# Geometry and rotations


def _flat(v: np.ndarray, f: np.ndarray):
    """Flat-shaded copy of a triangle mesh: (3F, 3) vertices, (3F, 3) unit face normals, (F, 3) faces."""
    tri = np.asarray(v, dtype=np.float64)[np.asarray(f)]                     # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(length > 0, n / np.where(length > 0, length, 1.0), np.array([0.0, 0.0, 1.0]))
    return tri.reshape(-1, 3), np.repeat(n, 3, axis=0), np.arange(3 * len(tri)).reshape(-1, 3)


def _rigid_inv(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4)."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions, xyzw, of rotation matrices (T, N, 3, 3), sign-continuous along T: (T, N, 4) float64."""
    m = R
    tr = [1 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2], 1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
          1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2], 1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]]
    a, b, c = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    d, e, f = m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2]
    cand = np.stack([np.stack(x, -1) for x in ([tr[0], a, b, c], [a, tr[1], d, e],   # rows: (w, x, y, z) * 4|w|,
                                               [b, d, tr[2], f], [c, e, f, tr[3]])], -2)  # * 4|x|, * 4|y|, * 4|z|
    k = np.argmax(np.stack(tr, -1), axis=-1)
    q = np.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]      # (T, N, 4) wxyz
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = q[..., [1, 2, 3, 0]]
    dot = np.sum(q[1:] * q[:-1], axis=-1)                                    # flip where the sign turns
    sign = np.cumprod(np.concatenate([np.ones_like(dot[:1]), np.where(dot < 0, -1.0, 1.0)]), axis=0)
    return q * sign[..., None]


# ---------------------------------------------------------------------------------------------------------------
# Building the glTF


class _Writer:
    """A GLTF2 being built and its binary blob; every accessor gets its own 4-byte aligned bufferView."""

    def __init__(self):
        self.g = gl.GLTF2(asset=gl.Asset(generator="torchhand export", version="2.0"))
        self.blob = bytearray()
        self.materials: dict = {}
        self.time: int = -1
        self.anim: gl.Animation | None = None

    def accessor(self, data: np.ndarray, target: int | None = None, bounds: bool = False) -> int:
        """data: (N, C) float32 or uint32, C in 1, 3, 4; bounds: write per-component min/max."""
        data = np.ascontiguousarray(data)
        self.blob += b"\0" * (-len(self.blob) % 4)
        self.g.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=data.nbytes,
                                                target=target))
        self.blob += data.tobytes()
        acc = gl.Accessor(bufferView=len(self.g.bufferViews) - 1, componentType=_UINT if data.dtype == np.uint32
                          else _FLOAT, count=len(data), type=_TYPES[data.shape[1]])
        if bounds:
            acc.min, acc.max = data.min(0).tolist(), data.max(0).tolist()
        self.g.accessors.append(acc)
        return len(self.g.accessors) - 1

    def material(self, kind: str) -> int:
        if kind not in self.materials:
            self.materials[kind] = len(self.g.materials)
            self.g.materials.append(gl.Material(name=kind, pbrMetallicRoughness=gl.PbrMetallicRoughness(
                baseColorFactor=list(COLORS[kind]), metallicFactor=0.0, roughnessFactor=0.7)))
        return self.materials[kind]

    def mesh(self, name: str, v: np.ndarray, n: np.ndarray, f: np.ndarray, material: str) -> int:
        """A one-primitive triangle mesh: vertices and normals (V, 3) metres, faces (F, 3)."""
        attributes = gl.Attributes(POSITION=self.accessor(np.asarray(v, np.float32), _ARRAY_BUFFER, bounds=True),
                                   NORMAL=self.accessor(np.asarray(n, np.float32), _ARRAY_BUFFER))
        indices = self.accessor(np.asarray(f, np.uint32).reshape(-1, 1), _ELEMENT_ARRAY_BUFFER)
        self.g.meshes.append(gl.Mesh(name=name, primitives=[gl.Primitive(
            attributes=attributes, indices=indices, material=self.material(material), mode=gl.TRIANGLES)]))
        return len(self.g.meshes) - 1

    def node(self, name: str, parent: int | None, **kw) -> int:
        """A node named ``name``, appended to ``parent``'s children (None: not attached)."""
        self.g.nodes.append(gl.Node(name=name, **kw))
        i = len(self.g.nodes) - 1
        if parent is not None:
            self.g.nodes[parent].children.append(i)
        return i

    def channel(self, node: int, path: str, values: np.ndarray, interpolation: str = "LINEAR") -> None:
        """Animate ``node``'s ``path`` with ``values`` (T, 3) or (T, 4) at the shared keyframe times."""
        self.anim.samplers.append(gl.AnimationSampler(input=self.time, interpolation=interpolation,
                                                      output=self.accessor(np.asarray(values, np.float32))))
        self.anim.channels.append(gl.AnimationChannel(sampler=len(self.anim.samplers) - 1,
                                                      target=gl.AnimationChannelTarget(node=node, path=path)))

    def animate(self, nodes, poses: np.ndarray) -> None:
        """Translation and rotation channels of ``nodes`` (int or list of N) from poses (T, N, 4, 4); the static
        TRS of each node is set to frame 0."""
        nodes = [nodes] if isinstance(nodes, int) else list(nodes)
        quat = _quat_xyzw(poses[..., :3, :3])
        for i, node in enumerate(nodes):
            self.g.nodes[node].translation = poses[0, i, :3, 3].tolist()
            self.g.nodes[node].rotation = quat[0, i].tolist()
            self.channel(node, "translation", poses[:, i, :3, 3])
            self.channel(node, "rotation", quat[:, i])
