"""Independent physical checks of a synthesis result directory, with exact geometry (no SDF grid).

:func:`check_result` reads ``DIR/scene/`` and ``DIR/solutions/*.npz`` and measures, for every frame of every
solution:

* hand-object penetration: the hand's surface samples (posed by forward kinematics from ``q`` and ``root_pose``)
  against the object mesh with trimesh's exact signed distance (samples farther than ``margin`` outside the
  object's bounding box cannot penetrate and are skipped);
* contact geometry: each contact point's exact distance to the object surface (trimesh) and to its hand link's
  collision capsule (closed form);
* friction: every hand force inside its cone (|f_t| <= mu f_n), every table force inside the table's cone;
* balance: sum of hand, table and gravity forces against m a, and their torques about the centre of mass against
  I alpha + omega x I omega, with a, omega, alpha from central differences of the object trajectory computed here
  with SciPy's rotations (independently of the synthesis code), relative to the weight m |g| (and m |g| times the
  object's size for torques);
* joint limits.

It returns the worst value of each figure per solution; :data:`LIMITS` holds the acceptance thresholds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.spatial.transform import Rotation

from ..errors import FileFormatError, MissingFileError
from ..hand import default_hand
from ..scene import load_scene

__all__ = ["LIMITS", "check_result", "check_solution"]

LIMITS = {"penetration_m": 0.002, "contact_object_m": 0.002, "contact_hand_m": 0.002, "cone_violation": 1e-3,
          "force_error_rel": 0.01, "torque_error_rel": 0.01, "limit_violation_rad": 1e-6}
"""Acceptance thresholds: metres; cone violation relative to the largest force of the frame; balance errors
relative to the object's weight (torques: weight times the object's largest extent)."""


def _object_dynamics(pose: np.ndarray, com_local: np.ndarray, inertia: np.ndarray, fps: float):
    """Central-difference COM acceleration, angular velocity and acceleration (world), one-sided at the ends."""
    T = pose.shape[0]
    R = pose[:, :3, :3]
    com = np.einsum("tij,j->ti", R, com_local) + pose[:, :3, 3]
    acc = np.zeros((T, 3))
    omega = np.zeros((T, 3))
    alpha = np.zeros((T, 3))
    if T >= 3:
        acc[1:-1] = (com[2:] - 2 * com[1:-1] + com[:-2]) * fps ** 2
        acc[0], acc[-1] = acc[1], acc[-2]
    if T >= 2:
        rel = Rotation.from_matrix(R[1:]) * Rotation.from_matrix(R[:-1]).inv()
        w_mid = rel.as_rotvec() * fps
        omega[1:-1] = 0.5 * (w_mid[1:] + w_mid[:-1])
        omega[0], omega[-1] = w_mid[0], w_mid[-1]
        if T >= 3:
            alpha[1:-1] = (w_mid[1:] - w_mid[:-1]) * fps
            alpha[0], alpha[-1] = alpha[1], alpha[-2]
    return com, acc, omega, alpha


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    u = np.clip(np.einsum("...i,...i->...", p - a, ab) / np.maximum(np.einsum("...i,...i->...", ab, ab), 1e-18), 0, 1)
    return np.linalg.norm(p - (a + u[..., None] * ab), axis=-1)


def check_solution(scene, arrays: dict, margin: float = 0.005) -> dict:
    """Worst values of every checked figure over the frames of one solution (see the module docstring)."""
    mesh = scene.object.mesh
    pose = np.asarray(arrays["object_pose"], dtype=np.float64)
    T = pose.shape[0]
    sides = [h.side for h in scene.hands]
    two = len(sides) > 1
    hands = {h.side: default_hand(h.side, h.length) for h in scene.hands}
    lo_box, hi_box = mesh.bounds[0] - margin, mesh.bounds[1] + margin
    inv = np.linalg.inv(pose)
    out = {k: 0.0 for k in LIMITS}
    poses_by_side = {}
    for side in sides:
        hand = hands[side]
        q = np.asarray(arrays[f"q_{side}"] if two else arrays["q"], dtype=np.float64)
        root = np.asarray(arrays[f"root_pose_{side}"] if two else arrays["root_pose"], dtype=np.float64)
        lim = hand.joint_limits.numpy()
        out["limit_violation_rad"] = max(out["limit_violation_rad"],
                                         float(np.maximum(lim[:, 0] - q, q - lim[:, 1]).max()))
        poses = hand.forward_kinematics(torch.from_numpy(q), torch.from_numpy(root)).numpy()   # (T, L, 4, 4)
        poses_by_side[side] = poses
        S = hand.sample_points.numpy()
        link = hand.sample_link.numpy()
        P = poses[:, link]                                                        # (T, S, 4, 4)
        world = np.einsum("tsij,sj->tsi", P[..., :3, :3], S) + P[..., :3, 3]
        local = np.einsum("tij,tsj->tsi", inv[:, :3, :3], world) + inv[:, None, :3, 3]
        near = np.all((local >= lo_box) & (local <= hi_box), axis=-1)
        if near.any():
            sd_inside = trimesh.proximity.signed_distance(mesh, local[near])      # positive inside (trimesh)
            out["penetration_m"] = max(out["penetration_m"], float(np.max(sd_inside, initial=0.0)))
    # contacts
    mask = np.asarray(arrays["contact_mask"], dtype=bool)
    names = [str(n) for n in arrays["contact_link_name"]]
    links = np.asarray(arrays["contact_link"])
    cp = np.asarray(arrays["contact_point"], dtype=np.float64)
    cn = np.asarray(arrays["contact_normal"], dtype=np.float64)
    cf = np.asarray(arrays["contact_force"], dtype=np.float64)
    mu = float(arrays["friction"])
    if mask.any():
        t_idx, k_idx = np.nonzero(mask)
        p_obj = np.einsum("nij,nj->ni", inv[t_idx, :3, :3], cp[t_idx, k_idx]) + inv[t_idx, :3, 3]
        d_obj = np.abs(trimesh.proximity.signed_distance(mesh, p_obj))
        out["contact_object_m"] = float(d_obj.max())
        d_hand = np.zeros(len(t_idx))
        for n, (t, k) in enumerate(zip(t_idx, k_idx)):
            name = names[links[t, k]]
            side, lname = (name.split("/", 1) if two else (sides[0], name))
            hand = hands[side]
            li = hand.link_index(lname)
            T_l = poses_by_side[side][t, li]
            a = T_l[:3, :3] @ hand.capsule_a[li].numpy() + T_l[:3, 3]
            b = T_l[:3, :3] @ hand.capsule_b[li].numpy() + T_l[:3, 3]
            d_hand[n] = abs(_segment_distance(cp[t, k], a, b) - float(hand.capsule_radius[li]))
        out["contact_hand_m"] = float(d_hand.max())
        f = cf[t_idx, k_idx]
        n_ = cn[t_idx, k_idx] / np.linalg.norm(cn[t_idx, k_idx], axis=-1, keepdims=True)
        fn = np.einsum("ni,ni->n", f, n_)
        ft = np.linalg.norm(f - fn[:, None] * n_, axis=-1)
        scale = np.maximum(np.linalg.norm(cf, axis=-1).max(-1)[t_idx], 1e-9)
        out["cone_violation"] = float(np.max(np.maximum(ft - mu * fn, -fn) / scale, initial=0.0))
    emask = np.asarray(arrays["env_contact_mask"], dtype=bool)
    ef = np.asarray(arrays["env_contact_force"], dtype=np.float64)
    ep = np.asarray(arrays["env_contact_point"], dtype=np.float64)
    if emask.any():
        f = ef[emask]
        ft = np.linalg.norm(f[:, :2], axis=-1)
        scale = max(np.linalg.norm(f, axis=-1).max(), 1e-9)
        v = np.maximum(ft - scene.environment.friction * f[:, 2], -f[:, 2]) / scale
        out["cone_violation"] = max(out["cone_violation"], float(v.max()))
    # balance
    obj = scene.object
    com, acc, omega, alpha = _object_dynamics(pose, np.asarray(obj.com), np.asarray(obj.inertia), float(arrays["fps"]))
    g = scene.gravity.numpy()
    I_w = np.einsum("tij,jk,tlk->til", pose[:, :3, :3], np.asarray(obj.inertia), pose[:, :3, :3])
    F = (cf * mask[..., None]).sum(1) + (ef * emask[..., None]).sum(1) + obj.mass * g
    tau = (np.cross(cp - com[:, None], cf) * mask[..., None]).sum(1) + \
        (np.cross(ep - com[:, None], ef) * emask[..., None]).sum(1)
    Iw = np.einsum("tij,tj->ti", I_w, omega)
    tau_req = np.einsum("tij,tj->ti", I_w, alpha) + np.cross(omega, Iw)
    weight = obj.mass * np.linalg.norm(g)
    size = float(np.max(mesh.extents))
    out["force_error_rel"] = float(np.linalg.norm(F - obj.mass * acc, axis=-1).max() / weight)
    out["torque_error_rel"] = float(np.linalg.norm(tau - tau_req, axis=-1).max() / (weight * size))
    out["frames"] = T
    return out


def check_result(directory, margin: float = 0.005) -> list[dict]:
    """:func:`check_solution` for every ``solutions/sol_*.npz`` of a result directory, in index order."""
    d = Path(directory)
    if not (d / "scene").is_dir():
        raise MissingFileError(f"{d}: not a synthesis result directory (no scene/ in it)")
    scene = load_scene(d / "scene")
    reports = []
    for path in sorted((d / "solutions").glob("sol_*.npz")):
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError) as err:
            raise FileFormatError(f"{path}: not a readable npz ({err})") from None
        reports.append(dict(check_solution(scene, arrays, margin), file=path.name))
    return reports
