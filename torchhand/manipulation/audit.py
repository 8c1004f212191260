"""Measurements of a written manipulation result that the checker does not make (Liu 2009's acceptance figures),
read from the result directory only: the stored torques against MuJoCo's, the slip of static contacts and the
direction of sliding ones (Eq. 7).

* :func:`mujoco_torque_error`: the result's ``hand.xml`` in MuJoCo at every frame's root pose and joint angles:
  the generalised forces that move the hand as written against gravity and the object's reaction are
  ``qfrc_inverse + J^T f`` (``mj_inverse`` with the frames' velocities and accelerations, from MuJoCo's own
  ``mj_differentiatePos`` of consecutive frames, central at each frame and one-sided at the ends; zero for a result
  whose stats.json says ``dynamics`` is not ``"full"``; ``mj_applyFT`` of the force f each contact applies to the
  object, at its hand point); mapped to torchhand's order (torque about the root origin, force, joint torques) and
  compared with ``torque``.
* :func:`contact_motion`: the material points of every hand contact, placed by forward kinematics of the stored
  motion (the hand point, ``contact_hand_local``) and by the stored object pose (the object point,
  ``contact_object_local``), differenced over each frame: their tangential relative velocity (where the contact
  crossed an edge within the frame, the smaller of its tangential speeds about the two faces' normals). Static contacts
  should not move (at most 1 mm/s); a sliding one's friction force on the object should point along the hand
  point's velocity relative to the object (Eq. 7: the hand drags the object's surface with it).

Needs ``mujoco`` for the torques (a test extra).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..check.mjcf_geometry import _quat_wxyz

__all__ = ["ContactMotion", "contact_motion", "mujoco_torque_error"]

SLIDE_SPEED = 1e-3
"""Tangential speed above which a contact counts as moving (m/s): the static-slip bound."""


def _sides(d: Path, z: dict) -> list[tuple]:
    """Per hand of the result: (side or None for one hand, its hand file, q (T, D), root (T, 4, 4), torque
    (T, 6 + D), joint names, the prefix of its contact link names)."""
    from ..scene import load_scene

    sides = [h.side for h in load_scene(d / "scene").hands]
    if len(sides) == 1 or "q_" + sides[0] not in z:
        return [(None, d / "hand.xml", z["q"], z["root_pose"], z["torque"], [str(n) for n in z["joint_names"]], "")]
    return [(s, d / ("hand.xml" if i == 0 else f"hand_{s}.xml"), z[f"q_{s}"], z[f"root_pose_{s}"], z[f"torque_{s}"],
             [str(n) for n in z[f"joint_names_{s}"]], f"{s}/") for i, s in enumerate(sides)]


def mujoco_torque_error(result_dir) -> tuple[float, float]:
    """(largest |stored torque - MuJoCo's| over the frames, generalised forces and hands, largest |stored torque|)
    of a manipulation result directory (module docstring; two hands: each hand's file and ``torque_<side>``, with
    its own contacts). Raises ImportError without ``mujoco``."""
    import mujoco

    d = Path(result_dir)
    with np.load(d / "solutions" / "sol_000.npz") as f:
        z = {k: f[k] for k in f.files}
    stats = json.loads((d / "stats.json").read_text()) if (d / "stats.json").exists() else {}
    moving = stats.get("dynamics", "quasi-static") == "full"
    fps = float(stats.get("fps", 30.0))
    link_names = [str(n) for n in z["contact_link_name"]]
    worst, scale = 0.0, 0.0
    for _, xml, q_all, roots, torque, names, prefix in _sides(d, z):
        m = mujoco.MjModel.from_xml_path(str(xml))
        m.dof_armature[:] = 0
        m.dof_damping[:] = 0
        m.jnt_stiffness[:] = 0
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
        jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
        if m.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE or min(jid) <= 0:
            raise ValueError(f"{xml}: expected a free root joint and the result's joints")
        qadr, dadr = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
        data = mujoco.MjData(m)
        scale = max(scale, float(np.abs(torque).max()))
        D = len(names)
        qpos = np.tile(m.qpos0, (q_all.shape[0], 1))
        qpos[:, :3] = roots[:, :3, 3]
        qpos[:, 3:7] = [_quat_wxyz(r[:3, :3]) for r in roots]
        qpos[:, qadr] = q_all
        qvel, qacc = _mujoco_rates(m, qpos, roots, fps) if moving else (np.zeros((len(qpos), m.nv)),) * 2
        for t in range(q_all.shape[0]):
            root = roots[t]
            data.qpos[:], data.qvel[:], data.qacc[:] = qpos[t], qvel[t], qacc[t]
            mujoco.mj_inverse(m, data)
            qfrc = data.qfrc_inverse.copy()
            for k in np.flatnonzero(z["contact_mask"][t]):
                name = link_names[z["contact_link"][t, k]]
                if not name.startswith(prefix):
                    continue                               # the other hand's contact
                body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name[len(prefix):])
                point = data.xmat[body].reshape(3, 3) @ z["contact_hand_local"][t, k] + data.xpos[body]
                mujoco.mj_applyFT(m, data, z["contact_force"][t, k], np.zeros(3), point, body, qfrc)
            S = np.zeros((m.nv, 6 + D))
            S[0:3, 3:6] = np.eye(3)
            S[3:6, 0:3] = root[:3, :3].T
            S[dadr, 6 + np.arange(D)] = 1
            worst = max(worst, float(np.abs(S.T @ qfrc - torque[t]).max()))
    return worst, scale


def _mujoco_rates(m, qpos: np.ndarray, roots: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """qvel and qacc (T, nv) of MuJoCo's model ``m`` along the frames ``qpos`` (T, nq): half-step velocities by
    ``mj_differentiatePos`` (a free joint's angular part in the body's axes at the earlier frame, turned to world
    axes), averaged at each frame and differenced for the acceleration, one-sided at the ends (the stored torques'
    rule, docs/manipulation.md); the free joint's angular rates back in the body's axes at each frame."""
    import mujoco

    T, dt = len(qpos), 1.0 / fps
    half = np.zeros((max(T - 1, 0), m.nv))
    for t in range(T - 1):
        mujoco.mj_differentiatePos(m, half[t], dt, qpos[t], qpos[t + 1])
        half[t, 3:6] = roots[t][:3, :3] @ half[t, 3:6]              # world angular velocity
    vel, acc = np.zeros((T, m.nv)), np.zeros((T, m.nv))
    if T >= 2:
        vel[0], vel[-1] = half[0], half[-1]
        vel[1:-1] = 0.5 * (half[:-1] + half[1:])
    if T >= 3:
        acc[1:-1] = (half[1:] - half[:-1]) / dt
        acc[0], acc[-1] = acc[1], acc[-2]
    for t in range(T):                                              # angular rates in the body's axes
        vel[t, 3:6] = roots[t][:3, :3].T @ vel[t, 3:6]
        acc[t, 3:6] = roots[t][:3, :3].T @ acc[t, 3:6]
    return vel, acc


@dataclass(frozen=True)
class ContactMotion:
    """Relative motion of the hand contacts of a result, frame t-1 -> t, for every contact active at both frames.

    static_pairs: contact-frames that are static at t (not sliding, not added); static_speed: their largest
        tangential speed, m/s (0 when there are none)
    sliding_pairs: contact-frames marked sliding at t whose material points move faster than ``SLIDE_SPEED`` and
        whose friction force is not zero; cos: for those, cos(friction force on the object, hand point velocity
        relative to the object point), (N,)
    """

    static_pairs: int
    static_speed: float
    sliding_pairs: int
    cos: np.ndarray

    def share_along(self, bound: float = 0.95) -> float:
        """Share of the moving sliding contact-frames whose friction lies within acos(bound) of the velocity
        (NaN when there are none)."""
        return float(np.mean(self.cos >= bound)) if len(self.cos) else float("nan")


EDGE_COS = math.cos(math.radians(45.0))
"""A contact whose object normal turns by more than 45 degrees between two frames has crossed an edge."""


def contact_motion(result_dir) -> ContactMotion:
    """:class:`ContactMotion` of a manipulation result directory (module docstring): the hands are the result's
    own (``load_result``; two hands: each contact on its side's hand and motion), the points its stored link-frame
    and object-frame contact points."""
    from ..io.result import load_result

    res = load_result(result_dir)
    with np.load(Path(result_dir) / "solutions" / "sol_000.npz") as f:
        z = {k: f[k] for k in f.files}
    pose, fps = z["object_pose"], float(z["fps"])
    # per contact link name: its hand model, that hand's motion and the link's index in it
    per_name = {}
    for side, _, q_all, roots, _, _, prefix in _sides(Path(result_dir), z):
        hand = res.hand_models[side] if side is not None else next(iter(res.hand_models.values()))
        for i, n in enumerate(hand.link_names):
            per_name[prefix + n] = (hand, q_all, roots, i)
    names = [str(s) for s in z["contact_link_name"]]
    slot = z["contact_slot"]
    static_speed, static_pairs, cos = 0.0, 0, []
    for t in range(1, pose.shape[0]):
        prev_col = {int(s): j for j, s in enumerate(slot[t - 1]) if s >= 0}
        for j in np.flatnonzero(z["contact_mask"][t]):
            i = prev_col.get(int(slot[t, j]))
            if i is None:
                continue
            hand, q_all, roots, link = per_name[names[z["contact_link"][t - 1, i]]]
            h, p = z["contact_hand_local"][t - 1, i], z["contact_object_local"][t - 1, i]
            rel = []
            for s in (t - 1, t):
                T = hand.forward_kinematics(torch.as_tensor(q_all[s])[None],
                                            torch.as_tensor(roots[s])[None])[0, link].numpy()
                rel.append(T[:3, :3] @ h + T[:3, 3] - (pose[s][:3, :3] @ p + pose[s][:3, 3]))
            v = (rel[1] - rel[0]) * fps
            n = z["contact_normal"][t, j]
            vt = v - (v @ n) * n
            speed = float(np.linalg.norm(vt))
            n0 = z["contact_normal"][t - 1, i]
            if float(n @ n0) < EDGE_COS:
                # the point crossed an edge: its normal jumped from one face's to the other's within the frame, and
                # motion along the face it left is separation from that face, not slip; the smaller counts
                speed = min(speed, float(np.linalg.norm(v - (v @ n0) * n0)))
            if not z["contact_sliding"][t, j] and not z["contact_added"][t, j]:
                static_pairs += 1
                static_speed = max(static_speed, speed)
            elif z["contact_sliding"][t, j] and speed > SLIDE_SPEED:
                f = z["contact_force"][t, j]
                ft = f - (f @ n) * n
                if np.linalg.norm(ft) > 1e-9:
                    cos.append(float(ft @ vt) / (np.linalg.norm(ft) * speed))
    return ContactMotion(static_pairs, static_speed, len(cos), np.array(cos))
