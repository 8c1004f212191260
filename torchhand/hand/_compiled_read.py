"""A hand's plain specs from a model compiled by MuJoCo (:mod:`torchhand.hand._compile`).

:func:`read_compiled` reads the body tree below the hand's root body: bodies become links (MuJoCo's body order,
depth first), hinge and slide joints map one to one (MuJoCo's qpos order), collision geoms become geom specs, the
inertials are MuJoCo's (``body_mass``, ``body_ipos``, ``body_iquat``, ``body_inertia``), and joint couplings
(fixed tendons, joint equality constraints) are reported. Finger annotations come from
:mod:`torchhand.hand._topology` or from the ``<custom>`` elements torchhand writes. Conventions: metres, radians,
quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import FileFormatError, UnknownNameError
from ._mjcf_common import _ROOT_WRAPPER, _pose, _quat_to_mat
from ._specs import CouplingSpec, FingerSpec, GeomSpec, InertialSpec, JointSpec, LinkSpec

__all__ = ["CompiledTree", "read_compiled", "custom_annotations"]

_UNLIMITED = {"hinge": (-math.pi, math.pi), "slide": (-1.0, 1.0)}  # radians, metres
_GEOM_NAMES = {2: "sphere", 3: "capsule", 4: "ellipsoid", 5: "cylinder", 6: "box", 7: "mesh"}
_JOINT_FREE, _JOINT_BALL, _JOINT_SLIDE, _JOINT_HINGE = 0, 1, 2, 3


@dataclass(frozen=True)
class CompiledTree:
    """The hand's tree as plain specs, with what the finger finder needs.

    links, joints, geoms, inertials, couplings: specs (links parents first, joints in the order of the model's q);
    parent: parent link index per link (-1 for the root); link_joints: joint indices per link; name: the model's name
    """

    name: str
    links: tuple
    joints: tuple
    geoms: tuple
    inertials: tuple
    couplings: tuple
    parent: tuple
    link_joints: tuple


def read_compiled(model, path, root_body: str | None = None) -> CompiledTree:
    """The tree below the hand's root body of the compiled ``model`` (from file ``path``, for messages).

    The root body is ``root_body``, else the top-level body (a child of the world) with the most hinge and slide
    joints below it; a top body named ``torchhand_root`` (torchhand's free-joint wrapper) with one child is looked
    through, the child's pose in it becoming the root link's offset. Raises UnknownNameError (``root_body`` not
    found) or FileFormatError (no body with joints; a free joint below the root; a joint with a non-zero ``ref``;
    a plane, height-field or SDF collision geom).
    """
    import mujoco

    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}" for b in range(model.nbody)]
    root = _root_id(model, names, path, root_body)
    offset0 = np.eye(4)
    kids = [b for b in range(model.nbody) if b != 0 and model.body_parentid[b] == root]
    if names[root] == _ROOT_WRAPPER and len(kids) == 1:
        root = kids[0]
        offset0 = _body_pose(model, root)
    bodies = [b for b in range(root, model.nbody) if _below(model, b, root)]
    index = {b: i for i, b in enumerate(bodies)}
    links, parent, link_joints, joints, geoms, inertials = [], [], [], [], [], []
    for i, b in enumerate(bodies):
        up = index.get(int(model.body_parentid[b]), -1) if i else -1
        links.append(LinkSpec(names[b], names[bodies[up]] if up >= 0 else None,
                              offset0 if i == 0 else _body_pose(model, b)))
        parent.append(up)
        link_joints.append(_joints(model, b, names[b], path, joints, root))
        geoms.extend(_geoms(model, b, names[b], path))
        inertials.append(_inertial(model, b, names[b]))
    qnames = [j.name for j in joints]
    return CompiledTree(name=_model_name(model, path), links=tuple(links), joints=tuple(joints),
                        geoms=tuple(geoms), inertials=tuple(inertials),
                        couplings=tuple(_couplings(model, qnames)), parent=tuple(parent),
                        link_joints=tuple(tuple(j) for j in link_joints))


def _root_id(model, names: list, path, root_body: str | None) -> int:
    if root_body is not None:
        if root_body not in names[1:]:
            raise UnknownNameError(f"{path}: root_body {root_body!r} not found; bodies: {', '.join(names[1:])}")
        return names.index(root_body)
    tops = [b for b in range(1, model.nbody) if model.body_parentid[b] == 0]
    counts = {b: sum(1 for j in range(model.njnt) if model.jnt_type[j] in (_JOINT_HINGE, _JOINT_SLIDE, _JOINT_BALL)
                     and _below(model, int(model.jnt_bodyid[j]), b)) for b in tops}
    if not tops or max(counts.values()) == 0:
        raise FileFormatError(f"{path}: no body with hinge or slide joints below the world; not a hand")
    return max(tops, key=lambda b: (counts[b], -b))


def _below(model, b: int, root: int) -> bool:
    """Whether body ``b`` is ``root`` or one of its descendants."""
    while b > root:
        b = int(model.body_parentid[b])
    return b == root


def _body_pose(model, b: int) -> np.ndarray:
    return _pose(_quat_to_mat(model.body_quat[b]), model.body_pos[b])


def _joints(model, b: int, lname: str, path, out: list, root: int) -> list[int]:
    """Append the joints of body ``b`` to ``out`` as JointSpecs (a ball as three hinges ``NAME_x/_y/_z`` about the
    body axes); return their indices."""
    import mujoco

    mine = []
    for j in range(model.njnt):
        if int(model.jnt_bodyid[j]) != b:
            continue
        jname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
        jtype = int(model.jnt_type[j])
        if jtype == _JOINT_FREE:
            if b == root:
                continue
            raise FileFormatError(f"{path}: joint {jname!r} on body {lname!r}: a free joint below the hand's root")
        adr = int(model.jnt_qposadr[j])
        if jtype in (_JOINT_HINGE, _JOINT_SLIDE) and abs(float(model.qpos0[adr])) > 0:
            raise FileFormatError(f"{path}: joint {jname!r}: a non-zero ref ({float(model.qpos0[adr])!r}) is not "
                                  "supported")
        anchor = np.array(model.jnt_pos[j], dtype=np.float64)
        limited = bool(model.jnt_limited[j])
        if jtype == _JOINT_BALL:
            hi = float(model.jnt_range[j][1]) if limited else math.pi
            for k, ax in enumerate("xyz"):
                mine.append(len(out))
                out.append(JointSpec(f"{jname}_{ax}", lname, "hinge", np.eye(3)[k], anchor, np.array([-hi, hi])))
            continue
        kind = "hinge" if jtype == _JOINT_HINGE else "slide"
        lim = np.array(model.jnt_range[j], dtype=np.float64) if limited else np.array(_UNLIMITED[kind])
        mine.append(len(out))
        out.append(JointSpec(jname, lname, kind, np.array(model.jnt_axis[j], dtype=np.float64), anchor, lim))
    return mine


def _geoms(model, b: int, lname: str, path) -> list[GeomSpec]:
    """Collision geoms of body ``b`` (contype or conaffinity non-zero); an ellipsoid becomes a scaled icosphere."""
    import mujoco

    out = []
    for g in range(int(model.body_geomadr[b]), int(model.body_geomadr[b]) + int(model.body_geomnum[b])):
        if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
            continue
        gname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
        gtype = _GEOM_NAMES.get(int(model.geom_type[g]))
        if gtype is None:
            raise FileFormatError(f"{path}: geom {gname or g!r} on body {lname!r}: a plane, height field or SDF geom "
                                  "is not supported on a hand")
        pose = _pose(_quat_to_mat(model.geom_quat[g]), model.geom_pos[g])
        size = np.array(model.geom_size[g], dtype=np.float64)
        if gtype == "mesh":
            out.append(GeomSpec(lname, "mesh", np.zeros(3), pose, _mesh(model, int(model.geom_dataid[g])), gname))
        elif gtype == "ellipsoid":
            import trimesh

            s = trimesh.creation.icosphere(subdivisions=3)
            out.append(GeomSpec(lname, "mesh", np.zeros(3), pose,
                                (np.asarray(s.vertices) * size, np.asarray(s.faces)), gname))
        else:
            keep = {"sphere": 1, "capsule": 2, "cylinder": 2, "box": 3}[gtype]
            out.append(GeomSpec(lname, gtype, size[:keep], pose, None, gname))
    return out


def _mesh(model, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) in the compiled mesh frame (MuJoCo's float32 values) and faces (F, 3) of mesh ``m``."""
    va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
    fa, fn = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
    return (np.array(model.mesh_vert[va:va + vn], dtype=np.float64),
            np.array(model.mesh_face[fa:fa + fn], dtype=np.int64))


def _inertial(model, b: int, lname: str) -> InertialSpec:
    R = _quat_to_mat(model.body_iquat[b])
    inertia = R @ np.diag(np.array(model.body_inertia[b], dtype=np.float64)) @ R.T
    return InertialSpec(lname, float(model.body_mass[b]), np.array(model.body_ipos[b], dtype=np.float64), inertia)


def _couplings(model, qnames: list[str]) -> list[CouplingSpec]:
    """Fixed tendons over the hand's joints and joint equality constraints, as MuJoCo compiled them."""
    import mujoco

    jname = lambda j: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
    out = []
    for t in range(model.ntendon):
        adr, num = int(model.tendon_adr[t]), int(model.tendon_num[t])
        wraps = range(adr, adr + num)
        if any(int(model.wrap_type[w]) != int(mujoco.mjtWrap.mjWRAP_JOINT) for w in wraps):
            continue
        js = tuple(jname(int(model.wrap_objid[w])) for w in wraps)
        if set(js) <= set(qnames):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_TENDON, t) or f"tendon{t}"
            out.append(CouplingSpec("tendon", name, js, tuple(float(model.wrap_prm[w]) for w in wraps)))
    for e in range(model.neq):
        if int(model.eq_type[e]) != int(mujoco.mjtEq.mjEQ_JOINT):
            continue
        j1, j2 = int(model.eq_obj1id[e]), int(model.eq_obj2id[e])
        js = (jname(j1),) + ((jname(j2),) if j2 >= 0 else ())
        if set(js) <= set(qnames):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, e) or f"equality{e}"
            out.append(CouplingSpec("equality", name, js, tuple(float(v) for v in model.eq_data[e][:5])))
    return out


def _model_name(model, path) -> str:
    from pathlib import Path

    names = bytes(model.names)
    name = names[:names.find(b"\0")].decode(errors="replace") if b"\0" in names else ""
    return name or Path(path).stem


def custom_annotations(model, n_joints: int, path):
    """(side, length, q_rest or None, fingers) that torchhand's writer stored in ``<custom>``, or None."""
    import mujoco

    texts, nums = {}, {}
    for i in range(model.ntext):
        adr, size = int(model.text_adr[i]), int(model.text_size[i])
        texts[mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_TEXT, i)] = bytes(model.text_data[adr:adr + size - 1]).decode()
    for i in range(model.nnumeric):
        adr, size = int(model.numeric_adr[i]), int(model.numeric_size[i])
        nums[mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_NUMERIC, i)] = np.array(model.numeric_data[adr:adr + size])
    if "torchhand_side" not in texts:
        return None
    fingers, k = [], 0
    while f"torchhand_finger{k}" in texts:
        parts = texts[f"torchhand_finger{k}"].split("|")
        frame = nums.get(f"torchhand_finger{k}_frame")
        if len(parts) != 3 or frame is None or len(frame) != 6:
            raise FileFormatError(f'{path}: <text name="torchhand_finger{k}">: malformed torchhand finger annotation')
        fingers.append(FingerSpec(parts[0], tuple(parts[1].split()), frame[:3], frame[3:], tuple(parts[2].split())))
        k += 1
    q_rest = nums.get("torchhand_q_rest")
    if q_rest is not None and len(q_rest) != n_joints:
        raise FileFormatError(f'{path}: <numeric name="torchhand_q_rest">: expected {n_joints} values')
    return texts["torchhand_side"], float(nums.get("torchhand_length", [0.0])[0]), q_rest, fingers
