"""Test fixture: a small result directory written by hand, in the format of docs/result_format.md.

:func:`write_fixture_result` cuts a built-in scene to a few frames, puts each hand at its rest pose along its wrist
track (solution ``i`` flexes the fingers a little more), and fabricates hand-object contacts at the object surface
points closest to the fingertip pads in the first frame, fixed on the object from then on (with pressing forces and
some friction), object-table contacts with forces that carry the object's weight, and a ``stats.json``. It does
not run any synthesis.

Fabricated contact pattern per hand: thumb, index and middle touch in every frame, the ring finger from the middle
frame on, the little finger never; the index contact slides 2 mm per frame over the object from frame 4 on (marked in
``contact_sliding``). The render tests read a real ``torchhand synthesize`` output (:mod:`.real_result`) for one hand;
this fixture gives them two hands cheaply, and the render benchmark a clip of any length.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
import trimesh

import torchhand
from torchhand.hand.mjcf import save_mjcf
from torchhand.io.result import FORMAT_VERSION
from torchhand.scene import environment_contacts

FORCE_N = 3.0


def _to_np(x) -> np.ndarray:
    return x.detach().cpu().double().numpy()


def write_fixture_result(root: Path, scene_name: str = "box-turn", frames: int = 10, solutions: int = 2, *,
                         scene=None, q_ramp: float = 0.0) -> Path:
    """Write a result directory at ``root`` and return it.

    scene: a :class:`torchhand.scene.Scene` to use instead of the built-in ``scene_name`` (cut to ``frames``)
    q_ramp: radians added to the flexion joints linearly over the frames (0: a constant pose per solution)
    """
    root = Path(root)
    scene = (torchhand.load_scene(scene_name) if scene is None else scene).with_frames(0, frames)
    (root / "solutions").mkdir(parents=True, exist_ok=True)
    scene.export(root / "scene", overwrite=True)
    hands = {t.side: torchhand.default_hand(t.side, t.length) for t in scene.hands}
    for k, t in enumerate(scene.hands):
        save_mjcf(hands[t.side], root / ("hand.xml" if k == 0 else f"hand_{t.side}.xml"))
    obj_pose = _to_np(scene.object_pose)
    mesh: trimesh.Trimesh = scene.object.mesh
    env = environment_contacts(scene)
    env_mask = env.mask.numpy()
    env_point = _to_np(env.points)
    weight = scene.object.mass * 9.81
    env_force = np.zeros(env_point.shape)
    env_force[..., 2] = weight / np.maximum(env_mask.sum(-1, keepdims=True), 1)
    env_force *= env_mask[..., None]
    two = len(scene.hands) == 2
    for s in range(solutions):
        data: dict = {"format_version": np.array(FORMAT_VERSION), "reconstructed": np.array(True),
                      "fps": np.float64(scene.fps), "object_pose": obj_pose,
                      "strategy": np.array(["static", "sliding", "relocating", "mixed"][s % 4]),
                      "friction": np.float64(scene.friction), "env_contact_mask": env_mask,
                      "env_contact_point": env_point, "env_contact_force": env_force}
        names: list[str] = []
        c_mask, c_link, c_point, c_normal, c_force, c_slide = [], [], [], [], [], []
        for t in scene.hands:
            hand = hands[t.side]
            q = hand.q_rest.expand(frames, -1).clone()
            flex = hand.flexion_joints[hand.flexion_joints >= 0]
            q[:, flex] += 0.08 * s
            q[:, flex] += torch.linspace(0.0, q_ramp, frames, dtype=q.dtype)[:, None]
            root_pose = t.wrist_pose
            links = hand.forward_kinematics(q, root_pose)
            tip_T = links[:, hand.distal_link]  # (T, F, 4, 4)
            tips = _to_np((tip_T[..., :3, :3] @ hand.fingertip.unsqueeze(-1)).squeeze(-1) + tip_T[..., :3, 3])
            offset = len(names)
            names += [f"{t.side}/{n}" if two else n for n in hand.link_names]
            suffix = f"_{t.side}" if two else ""
            data[f"q{suffix}"] = _to_np(q)
            data[f"root_pose{suffix}"] = _to_np(root_pose)
            data[f"guiding{suffix}"] = np.tile(np.array([True, True, False, False, False]), (frames, 1))
            if two and t.side == "right":
                data["q"], data["root_pose"] = data["q_right"], data["root_pose_right"]
            mask = np.zeros((frames, 5), dtype=bool)
            mask[:, :3] = True
            mask[frames // 2:, 3] = True
            point = np.zeros((frames, 5, 3))
            normal = np.zeros((frames, 5, 3))
            # Contact points fixed on the object (closest to the pads in the first frame), the index one sliding.
            inv = np.linalg.inv(obj_pose[0])
            surf0, _, tri = trimesh.proximity.closest_point(mesh, tips[0] @ inv[:3, :3].T + inv[:3, 3])
            n_in = -mesh.face_normals[tri]
            for k in range(frames):
                surf = surf0.copy()
                if k >= 4:
                    surf[1] = surf[1] + (k - 3) * 0.002 * _tangent(mesh.face_normals[tri[1]])
                point[k] = surf @ obj_pose[k][:3, :3].T + obj_pose[k][:3, 3]
                normal[k] = n_in @ obj_pose[k][:3, :3].T
            tangent = np.stack([[_tangent(n) if np.linalg.norm(n) > 0 else np.zeros(3) for n in row]
                                for row in normal])
            force = FORCE_N * normal + 0.3 * FORCE_N * tangent
            c_mask.append(mask)
            c_link.append(np.where(mask, _to_np(hand.distal_link).astype(np.int64) + offset, -1))
            c_point.append(point * mask[..., None])
            c_normal.append(normal * mask[..., None])
            c_force.append(force * mask[..., None])
            slide = np.zeros((frames, 5), dtype=bool)
            slide[4:, 1] = True
            c_slide.append(slide)
        data.update(joint_names=np.array(hands[scene.hands[0].side].joint_names), contact_link_name=np.array(names),
                    contact_mask=np.concatenate(c_mask, 1), contact_link=np.concatenate(c_link, 1),
                    contact_point=np.concatenate(c_point, 1), contact_normal=np.concatenate(c_normal, 1),
                    contact_force=np.concatenate(c_force, 1), contact_sliding=np.concatenate(c_slide, 1))
        np.savez(root / "solutions" / f"sol_{s:03d}.npz", **data)
    stats = {"format_version": FORMAT_VERSION, "complete": True, "epsilon": 0.01, "T": frames, "time_s": 1.5,
             "solutions": solutions, "dead_ends": 3, "success_ratio": 0.4, "solution_ratio": 0.2, "nodes_tested": 1200,
             "nodes_per_second": 800.0}
    (root / "stats.json").write_text(json.dumps(stats))
    return root


def _tangent(n: np.ndarray) -> np.ndarray:
    t = np.cross(n, [0.0, 0.0, 1.0])
    if np.linalg.norm(t) < 1e-6:
        t = np.cross(n, [1.0, 0.0, 0.0])
    return t / np.linalg.norm(t)


def rest_pose_motion(frames: int = 10):
    """A hand-alone motion: the default right hand closing slowly, wrist fixed above the origin."""
    hand = torchhand.default_hand()
    q = hand.q_rest.expand(frames, -1).clone()
    flex = hand.flexion_joints[hand.flexion_joints >= 0]
    q[:, flex] += torch.linspace(0, 0.6, frames, dtype=q.dtype)[:, None]
    root = torch.eye(4, dtype=torch.float64).expand(frames, 4, 4).clone()
    root[:, 2, 3] = 0.1
    return hand, _to_np(q), _to_np(root)
