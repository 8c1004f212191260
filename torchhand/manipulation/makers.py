"""Grasps from existing motion: a frame of a ``torchhand synthesize`` result, or a MuJoCo qpos vector in a scene.

Both return an unsnapped :class:`~torchhand.manipulation.grasp.Grasp` (no contacts); :func:`make_grasp` runs
:func:`~torchhand.manipulation.snap.snap_grasp` on it against the scene's object.

* :func:`grasp_from_result`: solution ``N`` of a result directory (docs/result_format.md) at frame ``F``: its ``q``,
  its ``root_pose`` and its ``object_pose`` give ``wrist_in_object = object_pose[F]^-1 @ root_pose[F]``; the hand is
  the scene track's (``"default"`` at the track's length, or its MJCF file).
* :func:`grasp_from_qpos`: a hand file (MJCF or URDF) and a qpos vector of that model (MuJoCo's layout): the
  model is compiled by MuJoCo, ``mj_kinematics`` places its bodies; the hand is mounted on its hand frame as a scene mounts it
  (:func:`torchhand.hand.mount.track_hand`); joints are mapped by name; the wrist pose is read off the palm (the
  body the fingers branch from), so a free joint in the qpos, the root body's fixed pose, and palm joints the mount
  locks (the Shadow wrist, an arm's joints above the palm) all end up in the wrist pose; the object pose is the scene's at frame ``F``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..errors import FileFormatError, InputValueError, MissingFileError, ShapeError, UnknownNameError
from ..hand.mount import palm_link
from .grasp import Grasp, grasp_hand
from .snap import SNAP_TOL, SnapReport, snap_grasp

__all__ = ["grasp_from_result", "grasp_from_qpos", "make_grasp", "read_qpos"]


def _frame(frame, T: int, what: str) -> int:
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < T:
        raise InputValueError(f"--frame: expected an integer in [0, {T - 1}] ({what} has {T} frames), got {frame!r}")
    return int(frame)


def grasp_from_result(result_dir, *, solution: int = 0, frame: int = 0, side: str | None = None) -> tuple:
    """The grasp of solution ``solution`` at frame ``frame`` of a result directory.

    Returns (grasp (unsnapped), scene): the scene is the result's (its object is the one to snap onto).
    """
    from ..io.result import load_result

    result = load_result(result_dir)
    sol = result.solution(solution)
    side = side or sol.hands[0].side
    hs = sol.hand(side)
    f = _frame(frame, sol.T, f"solution {solution}")
    track = result.scene.hand(side)
    T_wo = sol.object_pose[f]
    wrist = np.linalg.solve(T_wo, hs.root_pose[f])
    wrist[3] = (0.0, 0.0, 0.0, 1.0)
    grasp = Grasp(hand=track.model, side=side, joint_names=tuple(hs.joint_names), q=hs.q[f].copy(),
                  wrist_in_object=wrist, frame=f, length=track.length)
    return grasp, result.scene


def read_qpos(path) -> np.ndarray:
    """A qpos vector from ``.npy`` (1-d, or (1, n)) or ``.txt`` (whitespace/comma separated numbers)."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"--qpos: file {path} does not exist")
    try:
        if path.suffix == ".npy":
            v = np.load(path, allow_pickle=False)
        else:
            v = np.array(path.read_text().replace(",", " ").split(), dtype=np.float64)
    except (OSError, ValueError) as err:
        raise FileFormatError(f"--qpos {path}: cannot read a vector of numbers ({err})") from None
    v = np.asarray(v, dtype=np.float64)
    if v.ndim == 2 and v.shape[0] == 1:
        v = v[0]
    if v.ndim != 1 or not np.isfinite(v).all():
        raise ShapeError(f"--qpos {path}: expected a finite 1-d vector, got shape {v.shape}")
    return v


def grasp_from_qpos(mjcf, qpos, scene, *, frame: int = 0, side: str | None = None) -> Grasp:
    """The grasp of a hand file's model at a qpos vector, on ``scene``'s object at ``frame`` (module docstring).

    Args:
        mjcf: the hand's MJCF or URDF file (the same file the qpos belongs to)
        qpos: the model's qpos vector, (nq,)
        scene: a :class:`~torchhand.scene.Scene` (its object pose at ``frame``)
        side: the hand's side (default: the scene's first hand)
    """
    import mujoco

    from ..hand._compile import compile_file

    path = Path(mjcf)
    if not path.is_file():
        raise MissingFileError(f"hand file {path} does not exist")
    side = side or scene.hands[0].side
    f = _frame(frame, scene.T, f"scene {scene.name}")
    model = compile_file(path)
    qpos = np.asarray(qpos, dtype=np.float64)
    if qpos.shape != (model.nq,):
        raise ShapeError(f"--qpos: expected {model.nq} values (the qpos of {path.name}), got shape {qpos.shape}")
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    grasp0 = Grasp(hand=str(path.resolve()), side=side, joint_names=(), q=np.zeros(0), wrist_in_object=np.eye(4),
                   frame=f)
    hand = grasp_hand(grasp0)
    # joints by name; joints the mount locks take their rest angle (their motion goes into the wrist pose)
    q = hand.q_rest.detach().cpu().double().numpy().copy()
    mj_names = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j): j for j in range(model.njnt)}
    lim = hand.joint_limits.detach().cpu().double().numpy()
    for d, name in enumerate(hand.joint_names):
        if name not in mj_names:
            raise UnknownNameError(f"{path}: joint {name!r} of the hand model is not in MuJoCo's model")
        j = mj_names[name]
        if lim[d, 0] < lim[d, 1]:
            q[d] = qpos[model.jnt_qposadr[j]]
    # the wrist from the palm: T_world_palm (MuJoCo) = wrist @ T_hand_palm (mounted model, palm joints at rest)
    palm = palm_link(hand)
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, hand.link_names[palm])
    if bid < 0:
        raise UnknownNameError(f"{path}: body {hand.link_names[palm]!r} not found by MuJoCo")
    T_world_palm = np.eye(4)
    T_world_palm[:3, :3] = data.xmat[bid].reshape(3, 3)
    T_world_palm[:3, 3] = data.xpos[bid]
    T_hand_palm = hand.forward_kinematics(torch.as_tensor(q)[None])[0, palm].detach().double().numpy()
    wrist_world = T_world_palm @ np.linalg.inv(T_hand_palm)
    T_wo = scene.object_pose[f].detach().cpu().double().numpy()
    wrist = np.linalg.solve(T_wo, wrist_world)
    wrist[3] = (0.0, 0.0, 0.0, 1.0)
    track = scene.hand(side) if side in scene.sides else None
    return Grasp(hand=str(path.resolve()), side=side, joint_names=tuple(hand.joint_names), q=q,
                 wrist_in_object=wrist, frame=f, length=track.length if track is not None else 0.19)


def make_grasp(grasp: Grasp, scene, *, tol: float = SNAP_TOL) -> tuple[Grasp, SnapReport]:
    """``grasp`` snapped onto ``scene``'s object (:func:`~torchhand.manipulation.snap.snap_grasp`)."""
    return snap_grasp(grasp, grasp_hand(grasp), scene.object.mesh, tol=tol)
