"""A DexYCB-style grasp-and-lift on a real scanned object: a YCB object from the shared reference data, lifted by an
arm-mounted Shadow hand whose grasp is given as a MuJoCo qpos vector.

DexYCB (Chao et al. 2021) records people grasping YCB objects and fits robot-free hand poses to them; a common use
is to retarget such a grasp to a robot hand on an arm, given as the qpos of the arm-and-hand model, and lift the
object. The shared reference data holds no DexYCB recording, so this case is **DexYCB-style, not DexYCB data**: the
object is the real YCB scan and its published mass, but the qpos (a fitted posture) and the object trajectory (a
minimum-jerk lift) are made here. :func:`ycb_lift_case` writes the three inputs of

    torchhand grasp from-qpos ARM.xml --qpos QPOS.npy --scene SCENE --frame 0 --out grasp.npz
    torchhand manipulate SCENE --grasp grasp.npz --out RESULT
    torchhand check RESULT

(``scripts/ycb_lift.py`` runs them; docs/manipulation.md, "A DexYCB-style grasp from a qpos (real scanned
object)"):

* the scene directory: the YCB scan (``meshes/ycb/<object>/textured.obj`` of the shared data, metres, not
  watertight; written into the scene directory at run time, never shipped) with its published mass
  (:data:`YCB_MASS`), standing upright on the table of the built-in scenes (z-up, ``TABLE_HEIGHT``, object-table
  friction 0.4, hand-object friction 0.8), at rest for ``REST`` frames, lifted 10 cm in 1 s with a minimum-jerk
  profile at 30 fps and held (48 frames);
* the arm file (:func:`arm_file`): the Shadow hand of the shared data (``hands/shadow_hand/right_hand.xml``) included
  under a 6-joint arm (three slides, three hinges) by MJCF ``<include>``;
* the qpos (``.npy``, the arm-and-hand model's MuJoCo layout): the arm joints placing the hand and the finger joints
  of the fitted grasp (:data:`_POSTURES`).

The grasp (the mustard bottle): the hand beside the bottle's +x side; the first, middle and ring fingertips
on the +y face around the waist (about 2 cm apart, the first on top), pointing into it, the thumb tip on the -y face
opposite them. It was fitted once (least squares over the wrist pose and the 22 finger joints, started from the
liu-shadow-lift posture turned so that its pinch spans the bottle's 6.4 cm thickness): first each of the five
fingertip capsules tangent to the scan's signed distance grid near a chosen point (x = 8 mm; z = 22, 0, -22, -42 mm
on the +y face, -2 mm on the -y face), the distal axes within 25 degrees of the surface normal, links of different
fingers at least 4 mm apart; then also the closest surface sample of each of the five distal links on the scan, every
other link's samples at least 6.5 mm from it and 4 mm above the table, every joint at least 1 degree inside its
limits. The result is stored rounded (0.1 degree, 0.1 mm, 1e-4 rad): building needs no search and is
deterministic. Afterwards the little finger was straightened (J3 26 -> 5, J2 45.5 -> 10, J1 22 -> 5 degrees) clear of
the bottle: its fingertip pad touched where the Shadow's fitted capsule lies 2.2 mm from its mesh, past the
checker's 2 mm contact-hand bound, so the grasp holds with four contacts (first, middle, ring, thumb).

Masses: B. Calli, A. Walsman, A. Singh, S. Srinivasa, P. Abbeel, A. M. Dollar, "Benchmarking in Manipulation
Research: The YCB Object and Model Set and Benchmarking Protocols", IEEE Robotics & Automation Magazine 22(3),
2015 (the object set paper's table of objects): 006_mustard_bottle 603 g, 003_cracker_box 411 g.

Conventions: metres, radians (postures written in degrees), column-vector 4x4 transforms, ``T_object_hand`` the
hand (wrist) frame in the object frame (:mod:`torchhand.conventions`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from ...errors import InputValueError, MissingFileError, UnknownNameError
from ...geometry.objects import RigidObject
from .._parts import HandTrack
from ._liu_postures import SHADOW_HAND, _posture, _rotvec_pose, shared_data_dir
from .ye_liu import TABLE_HEIGHT, _poses, _ramp, _scene

__all__ = ["FRAMES", "LIFT", "REST", "YCB_MASS", "YcbLiftCase", "arm_file", "arm_qpos", "ycb_grasp_pose",
           "ycb_lift_case", "ycb_lift_scene", "ycb_mesh_path"]

YCB_MASS = {"006_mustard_bottle": 0.603, "003_cracker_box": 0.411}
"""Published masses of the YCB objects in the shared data, kg (Calli et al. 2015, module docstring)."""

REST = 6
"""Frames at rest before the lift."""
LIFT = 0.10
"""Height of the lift, metres."""
_LIFT_FRAMES = 30          # 1 s at 30 fps
FRAMES = 48
"""Frames of the scene: rest, lift, hold."""

ARM_REACH = 1.0
"""Range of the arm's slides, +/- metres (the arm's base is at the world origin, the table top at 0.75 m)."""

# The fitted grasps (module docstring), per (object, hand): the finger joints in degrees (the other joints at 0, the
# file's rest) and the wrist in the object frame (rotation vector, position in metres).
_POSTURES = {
    ("006_mustard_bottle", "shadow"): (
        {"rh_FFJ4": -3.4, "rh_FFJ3": 12.3, "rh_FFJ2": 58.8, "rh_FFJ1": 70.9,
         "rh_MFJ4": -2.2, "rh_MFJ3": 23.9, "rh_MFJ2": 58.0, "rh_MFJ1": 35.5,
         "rh_RFJ4": 2.2, "rh_RFJ3": 25.9, "rh_RFJ2": 49.5, "rh_RFJ1": 46.1,
         "rh_LFJ5": 3.8, "rh_LFJ4": -1.6, "rh_LFJ3": 5.0, "rh_LFJ2": 10.0, "rh_LFJ1": 5.0,
         "rh_THJ5": -14.8, "rh_THJ4": 68.8, "rh_THJ3": 3.7, "rh_THJ2": 37.7, "rh_THJ1": 75.1},
        ((0.9681, 1.1006, 1.4471), (0.0831, -0.1007, -0.004)),
    ),
}
_HANDS = {"shadow": SHADOW_HAND}


class YcbLiftCase(NamedTuple):
    """What :func:`ycb_lift_case` wrote: the scene directory, the arm MJCF file, the qpos file (``.npy``), the frame
    the qpos belongs to, the object's name and its mass (kg)."""

    scene: Path
    arm: Path
    qpos: Path
    frame: int
    object: str
    mass: float


def _shared(shared_dir) -> Path:
    return Path(shared_dir) if shared_dir is not None else shared_data_dir()


def ycb_mesh_path(shared_dir=None, object: str = "006_mustard_bottle") -> Path:
    """The YCB scan ``meshes/ycb/<object>/textured.obj`` in the shared data (default: :func:`shared_data_dir`).

    Raises:
        UnknownNameError: an object without a published mass here; MissingFileError: the file is not there.
    """
    if object not in YCB_MASS:
        raise UnknownNameError(f"YCB object {object!r}: expected one of {', '.join(sorted(YCB_MASS))}")
    path = _shared(shared_dir) / "meshes" / "ycb" / object / "textured.obj"
    if not path.is_file():
        raise MissingFileError(f"YCB object {object}: the scan (meshes/ycb/{object}/textured.obj of the shared "
                               f"reference data) is not at {path}; set TORCHHAND_SHARED_DATA or pass the data "
                               f"directory")
    return path


def _hand_path(shared_dir, hand: str) -> Path:
    if hand not in _HANDS:
        raise UnknownNameError(f"hand {hand!r}: expected one of {', '.join(sorted(_HANDS))}")
    path = _shared(shared_dir) / _HANDS[hand]
    if not path.is_file():
        raise MissingFileError(f"hand {hand}: the file ({_HANDS[hand]} of the shared reference data) is not at "
                               f"{path}; set TORCHHAND_SHARED_DATA or pass the data directory")
    return path


def ycb_grasp_pose(hand_model, object: str = "006_mustard_bottle", hand: str = "shadow") -> tuple:
    """The fitted grasp of ``object`` by ``hand`` before snapping: (q (D,) radians of ``hand_model``,
    ``T_object_hand`` (4, 4)).

    Raises:
        UnknownNameError: no grasp is fitted for that object and hand.
    """
    key = (object, hand)
    if key not in _POSTURES:
        have = ", ".join(f"{o} with {h}" for o, h in _POSTURES)
        raise UnknownNameError(f"no fitted grasp for {object} with the {hand} hand (fitted: {have})")
    degrees, wrist = _POSTURES[key]
    _, q = _posture(hand_model, degrees, rest=False)
    return q, _rotvec_pose(*wrist)


def ycb_lift_scene(shared_dir=None, object: str = "006_mustard_bottle", hand: str = "shadow"):
    """The DexYCB-style lift as a :class:`~torchhand.scene.Scene`: the scan with its published mass upright on the
    table (its lowest point on the table plane, its mesh frame's axes kept: the scans stand on z), ``REST`` frames at
    rest, lifted ``LIFT`` in 30 frames (minimum jerk) and held to ``FRAMES``; the hand track is the hand of the shared
    data holding the object rigidly with :func:`ycb_grasp_pose` (``torchhand manipulate`` synthesizes the wrist; the
    track is the scene contract's).

    Raises:
        MissingFileError: the scan or the hand file is absent; UnknownNameError: an unknown object, hand or grasp.
    """
    import trimesh

    from ...hand.mount import track_hand

    mesh_path = ycb_mesh_path(shared_dir, object)
    hand_path = _hand_path(shared_dir, hand)
    mesh = trimesh.load(mesh_path, force="mesh")
    obj = RigidObject.from_trimesh(mesh, mass=YCB_MASS[object], name=object)
    z0 = TABLE_HEIGHT - float(obj.mesh.bounds[0, 2])
    up = LIFT * _ramp(FRAMES, REST, REST + _LIFT_FRAMES)
    pose = _poses(np.broadcast_to(np.eye(3), (FRAMES, 3, 3)), np.stack([0 * up, 0 * up, z0 + up], axis=-1))
    model = track_hand(HandTrack(side="right", wrist_pose=torch.eye(4, dtype=torch.float64)[None],
                                 model=str(hand_path)))
    _, T_object_hand = ycb_grasp_pose(model, object, hand)
    description = (f"DexYCB-style lift (fitted grasp, synthetic trajectory; not DexYCB data): the YCB scan {object} "
                   f"({YCB_MASS[object]} kg, Calli et al. 2015) standing on the table is lifted {100 * LIFT:.0f} cm "
                   f"in 1 s and held by the {hand} right hand")
    scene = _scene(f"ycb-lift-{object}", description, obj, pose, [("right", pose @ T_object_hand)])
    track = HandTrack(side="right", wrist_pose=scene.hands[0].wrist_pose, model=str(hand_path))
    return dataclasses.replace(scene, hands=(track,))


def arm_file(directory, hand_xml, reach: float = 0.3) -> Path:
    """An MJCF arm (three slides of +/- ``reach`` metres along x, y, z, then hinges about x, y, z) with the hand file
    ``hand_xml`` included under its last body (MJCF ``<include>``): writes ``hand_on_arm.xml`` (the hand file with
    its worldbody moved into the arm, its mesh directory made absolute) and ``scene.xml`` (which includes it) into
    ``directory``; returns the path of ``scene.xml``. The arm's joints are ``arm_tx``, ``arm_ty``, ``arm_tz``,
    ``arm_rx``, ``arm_ry``, ``arm_rz``; its base is at the world origin."""
    hand_xml = Path(hand_xml)
    directory = Path(directory)
    text = hand_xml.read_text()
    # the included file's body goes inside our arm: include a copy whose worldbody is our arm's last body
    inertial = "<inertial pos='0 0 0' mass='0.1' diaginertia='1e-4 1e-4 1e-4'/>"
    inner = text.replace("<worldbody>", f"<worldbody><body name='arm_base'>{inertial}"
                         "<joint name='arm_tx' type='slide' axis='1 0 0' range='-0.3 0.3'/>"
                         f"<body name='arm_l1'>{inertial}<joint name='arm_ty' type='slide' axis='0 1 0' range='-0.3 0.3'/>"
                         f"<body name='arm_l2'>{inertial}<joint name='arm_tz' type='slide' axis='0 0 1' range='-0.3 0.3'/>"
                         f"<body name='arm_l3'>{inertial}<joint name='arm_rx' axis='1 0 0' range='-3 3'/>"
                         f"<body name='arm_l4'>{inertial}<joint name='arm_ry' axis='0 1 0' range='-3 3'/>"
                         f"<body name='arm_l5'>{inertial}<joint name='arm_rz' axis='0 0 1' range='-3 3'/>", 1)
    inner = inner.replace("</worldbody>", "</body></body></body></body></body></body></worldbody>", 1)
    inner = inner.replace("range='-0.3 0.3'", f"range='{-reach} {reach}'")
    inner = inner.replace('meshdir="assets"', f'meshdir="{hand_xml.parent.resolve() / "assets"}"')
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "hand_on_arm.xml").write_text(inner)
    (directory / "scene.xml").write_text('<mujoco model="arm_scene"><compiler angle="radian"/>'
                                         '<include file="hand_on_arm.xml"/></mujoco>')
    return directory / "scene.xml"


def arm_qpos(arm_xml, hand_model, q: np.ndarray, T_world_hand: np.ndarray) -> np.ndarray:
    """The qpos of :func:`arm_file`'s model that puts ``hand_model`` (the hand file mounted on its hand frame,
    :func:`torchhand.hand.mount.track_hand`) at ``T_world_hand`` with joint angles ``q``: the arm's slides and XYZ
    hinges place its last body so that the hand's root body (the Shadow forearm) lands where the mounted model puts
    it; the finger joints are set by name.

    Raises:
        InputValueError: the pose needs a slide beyond the arm's range.
    """
    import mujoco
    from scipy.spatial.transform import Rotation

    from ...hand._compile import compile_file

    m = compile_file(arm_xml)
    root = hand_model.link_names[0]
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, root)
    W = np.asarray(T_world_hand, dtype=np.float64) @ hand_model.chain.link_offset[0].double().numpy()
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, m.body_quat[bid])
    P = np.eye(4)
    P[:3, :3], P[:3, 3] = R.reshape(3, 3), m.body_pos[bid]
    A = W @ np.linalg.inv(P)                       # the arm's last body in the world
    adr = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j): int(m.jnt_qposadr[j]) for j in range(m.njnt)}
    qpos = m.qpos0.copy()
    for n, v in zip(("arm_tx", "arm_ty", "arm_tz"), A[:3, 3]):
        lo, hi = m.jnt_range[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]
        if not lo <= v <= hi:
            raise InputValueError(f"arm: {n} = {v:.3f} m is outside the slide's range [{lo:g}, {hi:g}]")
        qpos[adr[n]] = v
    qpos[[adr["arm_rx"], adr["arm_ry"], adr["arm_rz"]]] = Rotation.from_matrix(A[:3, :3]).as_euler("XYZ")
    for n, v in zip(hand_model.joint_names, np.asarray(q, dtype=np.float64)):
        qpos[adr[n]] = v
    return qpos


def ycb_lift_case(shared_dir, out_dir, *, object: str = "006_mustard_bottle", hand: str = "shadow") -> YcbLiftCase:
    """Write the DexYCB-style lift (module docstring) into ``out_dir``: ``scene/`` (scene directory), ``arm/scene.xml``
    (with ``arm/hand_on_arm.xml``) and ``qpos.npy`` (frame 0 of the scene). ``shared_dir`` is the shared reference
    data directory (None: :func:`shared_data_dir`). Existing files of a previous case are replaced.

    Raises:
        MissingFileError: the scan or the hand file is absent (one line naming the path);
        UnknownNameError: an unknown object or hand, or no fitted grasp for them.
    """
    from ...hand.mount import track_hand
    from .._writer import export_scene_dir

    scene = ycb_lift_scene(shared_dir, object, hand)
    out = Path(out_dir)
    scene_dir = export_scene_dir(scene, out / "scene", overwrite=True)
    arm = arm_file(out / "arm", _hand_path(shared_dir, hand), reach=ARM_REACH)
    model = track_hand(scene.hands[0])
    q, T_object_hand = ycb_grasp_pose(model, object, hand)
    T_world_hand = scene.object_pose[0].double().numpy() @ T_object_hand
    qpos = arm_qpos(arm, model, q, T_world_hand)
    qpos_path = out / "qpos.npy"
    np.save(qpos_path, qpos)
    return YcbLiftCase(scene=scene_dir, arm=arm, qpos=qpos_path, frame=0, object=object, mass=YCB_MASS[object])
