"""Penetration of a robot hand measured on its own MJCF collision geoms, posed by MuJoCo's kinematics.

For a hand whose geometry is not all capsules (a robot hand from MJCF), one capsule fitted per link would stand
off boxes and meshes by centimetres, so the checker measures those hands here instead: the result's ``hand.xml``
is loaded in MuJoCo (not in torchhand's model), ``qpos = (root position, root quaternion wxyz, q)`` is set per
frame and ``mj_kinematics`` poses every collision geom (``contype`` or ``conaffinity`` non-zero). Each geom is a
triangle mesh in its own frame (MuJoCo's sizes; mesh geoms from MuJoCo's compiled ``mesh_vert``/``mesh_face``).

Depth of a link in the object (metres, the largest over the link's geoms and the frame):
    * points on each geom's surface (its vertices and an even sample ``spacing`` apart), their signed distance
      into the object mesh (trimesh, positive inside), and
    * the object's vertices inside each geom, their distance to the geom's surface,
whichever is larger; 0 when nothing is inside. Exact where the deepest point is a geom or object vertex or a
sample; an edge of one crossing a face of the other between samples is under-measured by at most about
``spacing / 2`` of depth. Table: how far the lowest surface point lies below the plane.

Needs ``mujoco`` (a test extra); :func:`geom_depths` returns None without it and the checker keeps the capsules.
"""

from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["geom_depths"]

_TYPES = {2: "sphere", 3: "capsule", 5: "cylinder", 6: "box", 7: "mesh"}     # mjtGeom values


def geom_depths(xml_path, model, q: np.ndarray, root: np.ndarray, obj_mesh: trimesh.Trimesh,
                object_pose: np.ndarray, table_height: float | None, spacing: float = 0.002):
    """Per-link depths in the object and under the table from the MJCF geoms (module docstring).

    Args:
        xml_path: the result's hand file (``hand.xml``)
        model: the :class:`~torchhand.hand.HandModel` read from it (link and joint names)
        q: (T, D) radians, ``model.joint_names`` order; root: (T, 4, 4) the root poses
        obj_mesh: the object mesh (object frame); object_pose: (T, 4, 4)
        table_height: z of the table, or None
    Returns:
        (object depth (T, L), table depth (T, L) or None), metres, NaN for links without geoms; or None when
        MuJoCo is not installed.
    """
    try:
        import mujoco
    except ImportError:
        return None
    from torchhand.hand._link_geometry import geom_trimesh

    m = mujoco.MjModel.from_xml_path(str(xml_path))
    d = mujoco.MjData(m)
    T, L = q.shape[0], model.num_links
    link_of_body = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b): b for b in range(m.nbody)}
    body_link = {link_of_body[n]: i for i, n in enumerate(model.link_names) if n in link_of_body}
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    adr = [m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in model.joint_names]
    geoms = []                                     # (geom id, link, surface points (P, 3), mesh in geom frame)
    for g in range(m.ngeom):
        kind = _TYPES.get(int(m.geom_type[g]))
        link = body_link.get(int(m.geom_bodyid[g]))
        if kind is None or link is None or (m.geom_contype[g] == 0 and m.geom_conaffinity[g] == 0):
            continue
        mesh = None
        if kind == "mesh":
            k = int(m.geom_dataid[g])
            v0, nv = int(m.mesh_vertadr[k]), int(m.mesh_vertnum[k])
            f0, nf = int(m.mesh_faceadr[k]), int(m.mesh_facenum[k])
            mesh = (np.asarray(m.mesh_vert[v0:v0 + nv], dtype=np.float64), np.asarray(m.mesh_face[f0:f0 + nf]))
        tm = geom_trimesh(kind, np.asarray(m.geom_size[g], dtype=np.float64), mesh)
        count = max(int(tm.area / spacing ** 2), 1)
        pts = np.concatenate([np.asarray(tm.vertices), trimesh.sample.sample_surface_even(tm, count, seed=0)[0]])
        geoms.append((g, link, pts, tm))
    obj_depth = np.full((T, L), np.nan)
    tab_depth = np.full((T, L), np.nan) if table_height is not None else None
    verts = np.asarray(obj_mesh.vertices, dtype=np.float64)
    for t in range(T):
        d.qpos[:] = m.qpos0
        if free:
            a = m.jnt_qposadr[free[0]]
            d.qpos[a:a + 3] = root[t, :3, 3]
            d.qpos[a + 3:a + 7] = _quat_wxyz(root[t, :3, :3])
        d.qpos[adr] = q[t]
        mujoco.mj_kinematics(m, d)
        inv = np.linalg.inv(object_pose[t])
        world_verts = verts @ object_pose[t, :3, :3].T + object_pose[t, :3, 3]
        for g, link, pts, tm in geoms:
            R, p = d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g]
            world = pts @ R.T + p
            local = world @ inv[:3, :3].T + inv[:3, 3]
            depth = max(float(trimesh.proximity.signed_distance(obj_mesh, local).max()), 0.0)
            # object vertices inside the geom (a box corner pressing into a palm plate)
            in_geom = (world_verts - p) @ R
            near = np.linalg.norm(in_geom, axis=1) <= np.linalg.norm(tm.vertices, axis=1).max()
            if near.any():
                depth = max(depth, float(trimesh.proximity.signed_distance(tm, in_geom[near]).max()))
            obj_depth[t, link] = np.fmax(obj_depth[t, link], depth)
            if tab_depth is not None:
                tab_depth[t, link] = np.fmax(tab_depth[t, link], table_height - float(world[:, 2].min()))
    return obj_depth, tab_depth


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])
