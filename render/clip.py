"""What one panel of a video draws, as plain NumPy: posed hand links, the object, the table, contacts and forces.

A :class:`Clip` is built from a result directory's solution (:func:`clip_from_solution`) or from a bare hand motion
(:func:`clip_from_hand`: joint angles and wrist poses, no object). Conventions (see :mod:`torchhand.conventions`):
world z-up, metres, newtons; column-vector 4x4 transforms; contact forces are forces of the hand on the object.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from torchhand.errors import InputValueError, ShapeError

__all__ = ["HandTrackLinks", "Clip", "hand_link_poses", "clip_from_solution", "clip_from_hand", "clip_points",
           "force_scale"]


@dataclass(frozen=True, eq=False)
class HandTrackLinks:
    """One hand to draw: its model and its link poses ``T_world_link`` per frame, (T, L, 4, 4), metres."""

    hand: object  # torchhand.hand.HandModel
    link_poses: np.ndarray


@dataclass(frozen=True, eq=False)
class Clip:
    """Everything one panel draws, T frames (arrays are NumPy float64 / bool).

    hands: tuple of :class:`HandTrackLinks`
    fps: frames per second
    object_mesh: trimesh.Trimesh in the object frame, metres, or None; object_pose (T, 4, 4) or None
    table_height: z of the table plane, metres, or None for no table
    table_extent: (x_min, x_max, y_min, y_max) of a table with an edge (drawn as a block), or None (a table top
    under the camera's target); floor_height: z of a floor, metres, or None
    contact_mask (T, K) bool, contact_point (T, K, 3) world metres, contact_force (T, K, 3) newtons, or None
    env_contact_mask (T, E), env_contact_point (T, E, 3), env_contact_force (T, E, 3), or None
    labels: lines of text drawn on the panel
    """

    hands: tuple
    fps: float
    object_mesh: object = None
    object_pose: np.ndarray | None = None
    table_height: float | None = None
    table_extent: tuple | None = None
    floor_height: float | None = None
    contact_mask: np.ndarray | None = None
    contact_point: np.ndarray | None = None
    contact_force: np.ndarray | None = None
    env_contact_mask: np.ndarray | None = None
    env_contact_point: np.ndarray | None = None
    env_contact_force: np.ndarray | None = None
    labels: tuple = field(default_factory=tuple)

    @property
    def T(self) -> int:
        return int(self.hands[0].link_poses.shape[0]) if self.hands else int(self.object_pose.shape[0])

    def frames(self, start: int, stop: int) -> "Clip":
        """Frames ``start <= k < stop`` as a new clip."""
        s = slice(start, stop)

        def cut(a):
            return None if a is None else a[s]

        hands = tuple(HandTrackLinks(h.hand, h.link_poses[s]) for h in self.hands)
        return replace(self, hands=hands, object_pose=cut(self.object_pose), contact_mask=cut(self.contact_mask),
                       contact_point=cut(self.contact_point), contact_force=cut(self.contact_force),
                       env_contact_mask=cut(self.env_contact_mask), env_contact_point=cut(self.env_contact_point),
                       env_contact_force=cut(self.env_contact_force))


def hand_link_poses(hand, q: np.ndarray, root: np.ndarray, joint_names=None) -> np.ndarray:
    """Link poses of ``hand`` for joint angles ``q`` (T, D) radians and wrist poses ``root`` (T, 4, 4), world.

    joint_names: names of ``q``'s columns (D,); joints of ``hand`` not among them stay at the rest pose. None: ``q``
    is in ``hand.joint_names`` order.
    returns: ``T_world_link``, (T, L, 4, 4), float64
    """
    q = np.asarray(q, dtype=np.float64)
    root = np.asarray(root, dtype=np.float64)
    if q.ndim != 2 or root.shape != (q.shape[0], 4, 4):
        raise ShapeError(f"q, root: expected shapes (T, D) and (T, 4, 4), got {q.shape} and {root.shape}")
    h64 = hand.to("cpu", torch.float64)
    if joint_names is not None and tuple(joint_names) != tuple(h64.joint_names):
        full = np.tile(h64.q_rest.numpy(), (q.shape[0], 1))
        known = {n: i for i, n in enumerate(h64.joint_names)}
        cols = [(known[n], j) for j, n in enumerate(joint_names) if n in known]
        if not cols:
            raise InputValueError(f"joint_names: none of {list(joint_names)[:4]}... is a joint of hand "
                                  f"{h64.name!r} ({', '.join(h64.joint_names[:4])}, ...)")
        for i, j in cols:
            full[:, i] = q[:, j]
        q = full
    elif q.shape[1] != h64.num_joints:
        raise ShapeError(f"q: expected shape (T, {h64.num_joints}) for hand {h64.name!r}, got {q.shape}")
    with torch.no_grad():
        T = h64.forward_kinematics(torch.from_numpy(q), torch.from_numpy(root))
    return T.numpy()


def clip_from_hand(q: np.ndarray, root: np.ndarray, hand=None, *, fps: float = 30.0, joint_names=None,
                   labels=()) -> Clip:
    """A clip of a hand alone: joint angles ``q`` (T, D) radians, wrist poses ``root`` (T, 4, 4) world metres.

    hand: a :class:`~torchhand.hand.HandModel` (default: the default right hand).
    """
    if hand is None:
        from torchhand.hand import default_hand

        hand = default_hand()
    poses = hand_link_poses(hand, q, root, joint_names)
    return Clip(hands=(HandTrackLinks(hand, poses),), fps=float(fps), labels=tuple(labels))


def clip_from_solution(result, solution, *, labels=()) -> Clip:
    """The clip of ``solution`` (:class:`~torchhand.io.result.Solution`) in ``result``'s scene
    (:class:`~torchhand.io.result.Result`): hands, object, table, contacts and forces."""
    scene = result.scene
    hands = []
    for hs in solution.hands:
        model = result.hand_models.get(hs.side)
        if model is None:
            from torchhand.hand import default_hand

            model = default_hand(hs.side if hs.side in ("right", "left") else "right")
        hands.append(HandTrackLinks(model, hand_link_poses(model, hs.q, hs.root_pose, hs.joint_names)))
    env = scene.environment
    return Clip(hands=tuple(hands), fps=solution.fps, object_mesh=scene.object.mesh, object_pose=solution.object_pose,
                table_height=float(env.table_height) if env.table else None,
                table_extent=env.table_extent if env.table else None,
                floor_height=float(env.floor_height) if getattr(env, "floor", False) else None,
                contact_mask=solution.contact_mask, contact_point=solution.contact_point,
                contact_force=solution.contact_force, env_contact_mask=solution.env_contact_mask,
                env_contact_point=solution.env_contact_point, env_contact_force=solution.env_contact_force,
                labels=tuple(labels))


_CUBE = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


def clip_points(clip: Clip, with_table: bool = False) -> np.ndarray:
    """World points (N, 3) that should stay in view: hand surfaces (link capsule ends +- radius) and the object's
    bounding-box corners, over all frames."""
    pts = []
    for h in clip.hands:
        a = h.hand.capsule_a.detach().cpu().double().numpy()
        b = h.hand.capsule_b.detach().cpu().double().numpy()
        r = h.hand.capsule_radius.detach().cpu().double().numpy()
        P = h.link_poses
        for ends in (a, b):
            w = np.einsum("tlij,lj->tli", P[..., :3, :3], ends) + P[..., :3, 3]
            w = w[:, r > 0]
            pad = r[r > 0][None, :, None]
            for corner in _CUBE:  # the cube around each end sphere
                pts.append((w + pad * corner).reshape(-1, 3))
    if clip.object_mesh is not None and clip.object_pose is not None:
        lo, hi = clip.object_mesh.bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        Pp = clip.object_pose
        pts.append((np.einsum("tij,cj->tci", Pp[:, :3, :3], corners) + Pp[:, None, :3, 3]).reshape(-1, 3))
    return np.concatenate(pts) if pts else np.zeros((1, 3))


def force_scale(clips, target_length: float) -> tuple[float, float]:
    """Metres of arrow per newton so that the largest force over ``clips`` is about ``target_length`` metres, rounded
    so that one centimetre is a round number of newtons. Returns (metres per newton, newtons per centimetre)."""
    fmax = 0.0
    for c in clips:
        for mask, force in ((c.contact_mask, c.contact_force), (c.env_contact_mask, c.env_contact_force)):
            if mask is not None and force is not None and mask.any():
                fmax = max(fmax, float(np.linalg.norm(force[mask], axis=-1).max()))
    if fmax <= 0 or target_length <= 0:
        return 0.01, 1.0
    n_per_cm = fmax * 0.01 / target_length
    k = 10.0 ** np.floor(np.log10(n_per_cm))
    nice = next(m * k for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * k >= n_per_cm * 0.999)
    return 0.01 / nice, float(nice)
