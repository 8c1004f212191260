"""Drawing clips with pyrender: one offscreen context, one pyrender scene per panel, node poses updated per frame.

:class:`ClipRenderer` turns a :class:`~torchhand.render.clip.Clip` and a
:class:`~torchhand.render.camera.Camera` into RGB frames, (H, W, 3) uint8. Static meshes (hand links, object,
table) are built once and shared between panels; the contact dots and force arrows of each frame are instanced
meshes rebuilt per frame. Hand-object contacts are cyan dots, object-environment contacts yellow dots, forces red
arrows of ``metres_per_newton`` length per newton: a hand's force ends at its contact point (it pushes into the
object), the environment's starts at its contact point. pyrender is imported here, lazily, by the constructor.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .backend import offscreen_renderer
from .geometry import arrow_parts, arrow_transforms, dot_mesh, hand_link_meshes, table_mesh

__all__ = ["Style", "ClipRenderer"]


@dataclass(frozen=True)
class Style:
    """Colours (linear RGBA in [0, 1]), sizes (metres) and lighting of the drawings."""

    background: tuple = (0.97, 0.97, 0.98, 1.0)
    skin: tuple = (0.90, 0.64, 0.50, 1.0)
    object: tuple = (0.36, 0.54, 0.82, 1.0)
    object_alpha: float = 0.78
    table: tuple = (0.62, 0.62, 0.64, 1.0)
    contact: tuple = (0.0, 0.85, 0.95, 1.0)
    env_contact: tuple = (1.0, 0.82, 0.0, 1.0)
    force: tuple = (0.88, 0.08, 0.06, 1.0)
    dot_radius: float = 0.004
    arrow_radius: float = 0.0016
    head_radius: float = 0.0042
    head_length: float = 0.010
    metres_per_newton: float = 0.01
    shadows: bool = True
    capsule_sections: int = 32


class ClipRenderer:
    """Offscreen renderer of ``width`` x ``height`` frames; use as a context manager or call :meth:`close`.

    Raises:
        RenderBackendError: no offscreen OpenGL (the message says what to install).
    """

    def __init__(self, width: int, height: int, style: Style | None = None):
        self.width, self.height = int(width), int(height)
        self.style = style or Style()
        self._renderer = offscreen_renderer(self.width, self.height)  # chooses the platform, then imports pyrender
        import pyrender

        self._pr = pyrender
        self._hand_meshes: dict = {}
        self._object_meshes: dict = {}
        s = self.style
        mat = pyrender.MetallicRoughnessMaterial

        def glow(c):
            return mat(baseColorFactor=c, metallicFactor=0.0, roughnessFactor=0.6,
                       emissiveFactor=tuple(0.55 * v for v in c[:3]))

        self._dot = (pyrender.Mesh.from_trimesh(dot_mesh(s.dot_radius), material=glow(s.contact)).primitives[0],
                     pyrender.Mesh.from_trimesh(dot_mesh(s.dot_radius), material=glow(s.env_contact)).primitives[0])
        shaft, head = arrow_parts(s.arrow_radius, s.head_radius, s.head_length)
        self._arrow = (pyrender.Mesh.from_trimesh(shaft, material=glow(s.force)).primitives[0],
                       pyrender.Mesh.from_trimesh(head, material=glow(s.force)).primitives[0])

    # -- lifetime -------------------------------------------------------------------------------------------------
    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None

    def __enter__(self) -> "ClipRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- scene building -------------------------------------------------------------------------------------------
    def _hand_mesh_list(self, hand):
        key = id(hand)
        if key not in self._hand_meshes:
            mat = self._pr.MetallicRoughnessMaterial(baseColorFactor=self.style.skin, metallicFactor=0.0,
                                                     roughnessFactor=0.55)
            self._hand_meshes[key] = (hand, [(li, self._pr.Mesh.from_trimesh(m, material=mat, smooth=True))
                                             for li, m in hand_link_meshes(hand, self.style.capsule_sections)])
        return self._hand_meshes[key][1]

    def _object_mesh(self, mesh):
        key = id(mesh)
        if key not in self._object_meshes:
            s = self.style
            color = (*s.object[:3], s.object_alpha)
            mat = self._pr.MetallicRoughnessMaterial(baseColorFactor=color, metallicFactor=0.0, roughnessFactor=0.5,
                                                     alphaMode="BLEND" if s.object_alpha < 1 else "OPAQUE")
            # Flat shading for boxy meshes (sharp edges read better), smooth for curved ones.
            smooth = len(mesh.faces) > 200
            self._object_meshes[key] = (mesh, self._pr.Mesh.from_trimesh(mesh, material=mat, smooth=smooth))
        return self._object_meshes[key][1]

    def stage(self, clip, camera) -> "_Stage":
        """A pyrender scene for ``clip`` seen by ``camera``; draw its frames with :meth:`render`."""
        pr, s = self._pr, self.style
        scene = pr.Scene(bg_color=s.background, ambient_light=(0.32, 0.32, 0.34))
        hand_nodes = []
        for h in clip.hands:
            for li, mesh in self._hand_mesh_list(h.hand):
                hand_nodes.append((h, li, scene.add(mesh, pose=h.link_poses[0, li])))
        obj_node = None
        if clip.object_mesh is not None and clip.object_pose is not None:
            obj_node = scene.add(self._object_mesh(clip.object_mesh), pose=clip.object_pose[0])
        target = camera.target
        dist = float(np.linalg.norm(camera.poses[0, :3, 3] - target))
        tmat = pr.MetallicRoughnessMaterial(baseColorFactor=s.table, metallicFactor=0.0, roughnessFactor=0.9)
        for mesh in _environment_meshes(clip, target, dist):
            scene.add(pr.Mesh.from_trimesh(mesh, material=tmat, smooth=False))
        cam = pr.PerspectiveCamera(yfov=camera.yfov, aspectRatio=camera.aspect, znear=0.01, zfar=100.0)
        cam_node = scene.add(cam, pose=camera.poses[0])
        # Key light from above and behind the viewer's left, casting shadows; a soft fill from the camera side.
        key = np.array([-0.35, -0.45, -1.0])
        scene.add(pr.DirectionalLight(color=np.ones(3), intensity=2.8), pose=_light_pose(key))
        fill = scene.add(pr.PointLight(color=np.ones(3), intensity=0.0), pose=camera.poses[0])
        return _Stage(self, clip, camera, scene, hand_nodes, obj_node, cam_node, fill)

    def render(self, stage: "_Stage", frame: int) -> np.ndarray:
        """RGB image of ``frame`` of the stage's clip, (H, W, 3) uint8."""
        return stage.render(frame)


def _light_pose(direction: np.ndarray) -> np.ndarray:
    """Pose of a directional light shining along ``direction`` (pyrender lights shine along their -z)."""
    from .camera import look_at

    d = np.asarray(direction, dtype=np.float64)
    return look_at(-d, np.zeros(3), up=(0.0, 1.0, 0.0) if abs(d[2]) > 0.99 * np.linalg.norm(d) else (0, 0, 1))


class _Stage:
    """A clip's pyrender scene, its per-frame nodes and the overlay nodes of the current frame."""

    def __init__(self, owner: ClipRenderer, clip, camera, scene, hand_nodes, obj_node, cam_node, fill):
        self.owner, self.clip, self.camera, self.scene = owner, clip, camera, scene
        self.hand_nodes, self.obj_node, self.cam_node, self.fill = hand_nodes, obj_node, cam_node, fill
        self._overlay: list = []
        dist = float(np.linalg.norm(camera.poses[0, :3, 3] - camera.target))
        fill.light.intensity = 1.6 * dist ** 2  # point lights fall off with distance squared

    def _instanced(self, primitive, poses: np.ndarray):
        pr = self.owner._pr
        p = pr.Primitive(positions=primitive.positions, normals=primitive.normals, indices=primitive.indices,
                         material=primitive.material, poses=poses)
        self._overlay.append(self.scene.add(pr.Mesh(primitives=[p])))

    def _set_frame(self, frame: int) -> None:
        clip, s = self.clip, self.owner.style
        t = min(frame, clip.T - 1)
        for h, li, node in self.hand_nodes:
            self.scene.set_pose(node, h.link_poses[t, li])
        if self.obj_node is not None:
            self.scene.set_pose(self.obj_node, clip.object_pose[t])
        pose = self.camera.pose(frame)
        self.scene.set_pose(self.cam_node, pose)
        self.scene.set_pose(self.fill, pose)
        for node in self._overlay:
            self.scene.remove_node(node)
        self._overlay = []
        k = s.metres_per_newton
        tails, vecs = [], []
        for mask, point, force, dot, hand_side in (
                (clip.contact_mask, clip.contact_point, clip.contact_force, self.owner._dot[0], True),
                (clip.env_contact_mask, clip.env_contact_point, clip.env_contact_force, self.owner._dot[1], False)):
            if mask is None or point is None or not mask[t].any():
                continue
            p = point[t][mask[t]]
            poses = np.tile(np.eye(4), (len(p), 1, 1))
            poses[:, :3, 3] = p
            self._instanced(dot, poses)
            if force is not None:
                f = force[t][mask[t]] * k
                big = np.linalg.norm(f, axis=-1) > 1.5 * s.head_length
                tails.append(p[big] - f[big] if hand_side else p[big])
                vecs.append(f[big])
        if tails and sum(len(x) for x in tails):
            shaft, head = arrow_transforms(np.concatenate(tails), np.concatenate(vecs), s.head_length)
            self._instanced(self.owner._arrow[0], shaft)
            self._instanced(self.owner._arrow[1], head)

    def render(self, frame: int) -> np.ndarray:
        pr = self.owner._pr
        self._set_frame(frame)
        flags = pr.RenderFlags.SHADOWS_DIRECTIONAL if self.owner.style.shadows else pr.RenderFlags.NONE
        with warnings.catch_warnings():  # older PyOpenGL calls numpy's deprecated tostring() on read-back
            warnings.filterwarnings("ignore", category=DeprecationWarning, module="OpenGL")
            color, _ = self.owner._renderer.render(self.scene, flags=flags)
        return np.ascontiguousarray(color[..., :3])


def _environment_meshes(clip, target: np.ndarray, dist: float) -> list:
    """The table (a top under the camera's target, or its block when it has an edge) and the floor."""
    import trimesh

    out = []
    if clip.table_height is not None and clip.table_extent is None:
        out.append(table_mesh(target[:2], clip.table_height, 1.2 * dist))
    elif clip.table_height is not None:
        x0, x1, y0, y1 = clip.table_extent
        bottom = clip.floor_height if clip.floor_height is not None else clip.table_height - 0.02
        out.append(trimesh.creation.box(bounds=[[x0, y0, bottom], [x1, y1, clip.table_height]]))
    if clip.floor_height is not None:
        out.append(table_mesh(target[:2], clip.floor_height, 1.2 * dist + 0.5))
    return out
