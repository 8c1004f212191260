"""Penetration of a robot hand measured on its own MJCF collision geoms, posed by MuJoCo's kinematics.

For a hand whose geometry is not all capsules (a robot hand from MJCF), one capsule fitted per link would stand
off boxes and meshes by centimetres, so the checker measures those hands here instead: the result's ``hand.xml``
is loaded in MuJoCo (not in torchhand's model), ``qpos = (root position, root quaternion wxyz, q)`` is set per
frame and ``mj_kinematics`` poses every collision geom (``contype`` or ``conaffinity`` non-zero). Each geom is a
triangle mesh in its own frame (MuJoCo's sizes; mesh geoms from MuJoCo's compiled ``mesh_vert``/``mesh_face``).

Depth of a link in the object (metres, the largest over the link's geoms and the frame):
    * points on each geom's surface (its vertices and an even sample ``spacing`` apart), their signed distance
      into the object mesh (the checker's exact one, :meth:`.geometry.ObjectMesh.signed_distance`, positive inside;
      points that cannot reach the object skipped, see :func:`geom_depths`), and
    * the object's vertices inside each geom, their distance to the geom's surface,
whichever is larger; 0 when nothing is inside. Exact where the deepest point is a geom or object vertex or a
sample; an edge of one crossing a face of the other between samples is under-measured by at most about
``spacing / 2`` of depth. Table: how far the lowest surface point lies below the plane.

Finger-finger depth (:func:`geom_finger_depths`): for each pair of links of different fingers (the pairs of
:func:`~.penetration.finger_pairs`), the deepest surface point of one link's geoms inside the other's (the same
measure as the object's, with a 1 mm sample).

Contact-hand gap (:func:`geom_contact_gaps`): the distance of each contact point to the surface of its link's geoms
(the nearest of them; trimesh's closest point on the geom's triangle mesh, in the geom's frame).

Needs ``mujoco`` (a test extra); these functions return None without it and the checker keeps the capsules.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .geometry import ObjectMesh

__all__ = ["geom_depths", "geom_finger_depths", "geom_contact_gaps"]

_TYPES = {2: "sphere", 3: "capsule", 5: "cylinder", 6: "box", 7: "mesh"}     # mjtGeom values


def geom_depths(xml_path, model, q: np.ndarray, root: np.ndarray, obj: ObjectMesh,
                object_pose: np.ndarray, table_height: float | None, spacing: float = 0.002):
    """Per-link depths in the object and under the table from the MJCF geoms (module docstring).

    Args:
        xml_path: the result's hand file (``hand.xml``)
        model: the :class:`~torchhand.hand.HandModel` read from it (link and joint names)
        q: (T, D) radians, ``model.joint_names`` order; root: (T, 4, 4) the root poses
        obj: the object (:class:`~.geometry.ObjectMesh`, object frame); object_pose: (T, 4, 4)
        table_height: z of the table, or None; or a scene's ``Environment`` with a table edge or a floor (the
            depth of the geom points in its solids, :mod:`.ground`)
    Returns:
        (object depth (T, L), table depth (T, L) or None), metres, NaN for links without geoms; or None when
        MuJoCo is not installed.

    Balls that lie wholly outside the object are skipped: a ball outside the object's bounding box, or whose
    centre is outside the object and farther from its surface than its radius. Each geom's surface points are
    binned into balls of a few millimetres; only the points of the other balls get the object's exact signed
    distance (:meth:`~.geometry.ObjectMesh.signed_distance`, the capsule hands' measure), all of a frame in one
    query; the object's vertices are tested against a geom only when the ball about the geom's origin that holds
    it (radius: its farthest vertex) is not clear.
    """
    posed = _PosedGeoms.load(xml_path, model, spacing)
    if posed is None:
        return None
    T, L = q.shape[0], model.num_links
    obj_depth = np.full((T, L), np.nan)
    tab_depth = np.full((T, L), np.nan) if table_height is not None else None
    verts = np.asarray(obj.mesh.vertices, dtype=np.float64)
    ids = [g for g, _, _, _ in posed.geoms]
    reach = np.array([np.linalg.norm(tm.vertices, axis=1).max() for _, _, _, tm in posed.geoms])
    balls = [_balls(pts, _BALL) for _, _, pts, _ in posed.geoms]       # (centre (C, 3), radius (C,), label (P,))
    radius = np.concatenate([reach] + [r for _, r, _ in balls])
    d = posed.data
    for t in range(T):
        posed.pose(q[t], root[t])
        inv = np.linalg.inv(object_pose[t])
        R_all, p_all = d.geom_xmat[ids].reshape(-1, 3, 3), d.geom_xpos[ids]
        to_obj = inv[:3, :3] @ R_all                                     # geom frame -> object frame, per geom
        origin = p_all @ inv[:3, :3].T + inv[:3, 3]                      # the geoms' origins, object frame
        centres = [c @ to_obj[k].T + origin[k] for k, (c, _, _) in enumerate(balls)]
        clear = _clear(obj, np.concatenate([origin] + centres), radius)
        geom_clear, ball_clear = clear[:len(ids)], np.split(clear[len(ids):], np.cumsum([len(c) for c in centres]))
        world_verts = verts @ object_pose[t, :3, :3].T + object_pose[t, :3, 3]
        near_points, owner = [], []
        for k, (g, link, pts, tm) in enumerate(posed.geoms):
            R, p = R_all[k], p_all[k]
            world = pts @ R.T + p
            obj_depth[t, link] = np.fmax(obj_depth[t, link], 0.0)
            if tab_depth is not None:
                tab_depth[t, link] = np.fmax(tab_depth[t, link], _table_depth(table_height, world))
            keep = ~ball_clear[k][balls[k][2]]
            if keep.any():
                near_points.append(world[keep] @ inv[:3, :3].T + inv[:3, 3])
                owner.append(np.full(int(keep.sum()), link))
            if geom_clear[k]:
                continue
            # object vertices inside the geom (a box corner pressing into a palm plate)
            in_geom = (world_verts - p) @ R
            near = np.linalg.norm(in_geom, axis=1) <= reach[k]
            if near.any():
                depth = float(trimesh.proximity.signed_distance(tm, in_geom[near]).max())
                obj_depth[t, link] = np.fmax(obj_depth[t, link], depth)
        if near_points:
            sd = np.maximum(obj.signed_distance(np.concatenate(near_points)), 0.0)
            np.maximum.at(obj_depth[t], np.concatenate(owner), sd)
    return obj_depth, tab_depth


_BALL = 0.004
"""Side of the cells (metres) that bin a geom's surface points into balls for :func:`geom_depths`."""


def _balls(points: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (P, 3) binned into cubic cells of side ``cell``: each cell's ball (the centroid of its points and the
    distance to the farthest), (C, 3) and (C,), and each point's cell, (P,) long."""
    _, label = np.unique(np.floor(points / cell).astype(np.int64), axis=0, return_inverse=True)
    label = label.reshape(-1)
    C = int(label.max()) + 1 if len(label) else 0
    centre = np.zeros((C, 3))
    np.add.at(centre, label, points)
    centre /= np.bincount(label, minlength=C)[:, None]
    radius = np.zeros(C)
    np.maximum.at(radius, label, np.linalg.norm(points - centre[label], axis=1))
    return centre, radius, label


def _clear(obj: ObjectMesh, centre: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Which balls (centre (N, 3), object frame; radius (N,)) lie wholly outside the object: outside its bounding
    box by more than the radius, or with the centre outside the object and farther than the radius from its
    surface. (N,) bool."""
    lo, hi = obj.mesh.bounds
    box = np.linalg.norm(np.maximum(lo - centre, 0.0) + np.maximum(centre - hi, 0.0), axis=1)
    clear = box > radius
    ask = ~clear
    if ask.any():
        clear[ask] = -obj.signed_distance(centre[ask]) > radius[ask]
    return clear


class _PosedGeoms:
    """A hand file in MuJoCo with its collision geoms per link, posed frame by frame by ``mj_kinematics``."""

    def __init__(self, mujoco, m, model, geoms: list, adr: list, free: list):
        self.mujoco, self.m, self.data = mujoco, m, mujoco.MjData(m)
        self.geoms = geoms                        # (geom id, link, surface points (P, 3), trimesh) in geom frames
        self.by_link: dict[int, list] = {}
        for g in geoms:
            self.by_link.setdefault(g[1], []).append(g)
        self.adr, self.free = adr, free

    @classmethod
    def load(cls, xml_path, model, spacing: float | None = 0.002):
        """None when MuJoCo is not installed. ``spacing``: of the surface samples (None: the vertices only)."""
        try:
            import mujoco
        except ImportError:
            return None
        from torchhand.hand._link_geometry import geom_trimesh

        m = mujoco.MjModel.from_xml_path(str(xml_path))
        link_of_body = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b): b for b in range(m.nbody)}
        body_link = {link_of_body[n]: i for i, n in enumerate(model.link_names) if n in link_of_body}
        free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        adr = [m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in model.joint_names]
        geoms = []
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
                mesh = (np.asarray(m.mesh_vert[v0:v0 + nv], dtype=np.float64),
                        np.asarray(m.mesh_face[f0:f0 + nf]))
            tm = geom_trimesh(kind, np.asarray(m.geom_size[g], dtype=np.float64), mesh)
            pts = np.asarray(tm.vertices)
            if spacing is not None:
                count = max(int(tm.area / spacing ** 2), 1)
                pts = np.concatenate([pts, trimesh.sample.sample_surface_even(tm, count, seed=0)[0]])
            geoms.append((g, link, pts, tm))
        return cls(mujoco, m, model, geoms, adr, free)

    def pose(self, q: np.ndarray, root: np.ndarray) -> None:
        """Pose every geom: joint angles q (D,) radians in the model's joint order, root (4, 4)."""
        m, d = self.m, self.data
        d.qpos[:] = m.qpos0
        if self.free:
            a = m.jnt_qposadr[self.free[0]]
            d.qpos[a:a + 3] = root[:3, 3]
            d.qpos[a + 3:a + 7] = _quat_wxyz(root[:3, :3])
        d.qpos[self.adr] = q
        self.mujoco.mj_kinematics(m, d)


def geom_finger_depths(xml_path, model, q: np.ndarray, root: np.ndarray, pairs: np.ndarray,
                       spacing: float = 0.001):
    """Overlap of link pairs of different fingers on their MJCF geoms posed by MuJoCo.

    For two geoms whose bounding spheres overlap: the largest signed distance (trimesh, positive inside) of either
    geom's surface points (vertices and an even ``spacing`` sample) into the other geom, measured by trimesh for the
    points inside the other geom's bounding box (a lower bound of the clearance when none is inside); otherwise
    minus the gap between the bounding spheres (a lower bound of the clearance). MuJoCo's own ``mj_geomDistance`` is not used for
    the depth: on two boxes it reports half the overlap (MuJoCo 3.2.7).

    Args:
        xml_path, model, q (T, D), root (T, 4, 4): as in :func:`geom_depths`
        pairs: (Q, 2) link indices (:func:`~.penetration.finger_pairs`)
    Returns:
        (T, Q) metres, positive: penetration, negative: clearance; NaN for a pair where a link has no geoms. None
        when MuJoCo is not installed.
    """
    posed = _PosedGeoms.load(xml_path, model, spacing=spacing)
    if posed is None:
        return None
    T, d = q.shape[0], posed.data
    reach = {g[0]: float(np.linalg.norm(g[3].vertices, axis=1).max()) for g in posed.geoms}
    out = np.full((T, len(pairs)), np.nan)
    for t in range(T):
        posed.pose(q[t], root[t])
        R = {g[0]: d.geom_xmat[g[0]].reshape(3, 3).copy() for g in posed.geoms}
        p = {g[0]: d.geom_xpos[g[0]].copy() for g in posed.geoms}
        for k, (a, b) in enumerate(pairs):
            ga, gb = posed.by_link.get(int(a), []), posed.by_link.get(int(b), [])
            if not (ga and gb):
                continue
            worst = -np.inf
            for x in ga:
                for y in gb:
                    gap = np.linalg.norm(p[x[0]] - p[y[0]]) - reach[x[0]] - reach[y[0]]
                    if gap > 0:
                        worst = max(worst, -gap)
                        continue
                    for u, v in ((x, y), (y, x)):       # u's surface points in v's frame, against v's mesh
                        local = ((u[2] @ R[u[0]].T + p[u[0]]) - p[v[0]]) @ R[v[0]]
                        worst = max(worst, _depth_into(v[3], local))
            out[t, k] = worst
    return out


def _depth_into(mesh: trimesh.Trimesh, points: np.ndarray) -> float:
    """The largest signed distance (positive inside) of ``points`` (P, 3) into ``mesh``: exact when positive; when
    negative, a lower bound of the clearance. Only the points inside the mesh's bounding box go to trimesh (a point
    inside the mesh is inside its box); the others count with minus their distance to the box, which is at most
    their distance to the mesh."""
    lo, hi = mesh.bounds
    outside = np.linalg.norm(np.maximum(lo - points, 0.0) + np.maximum(points - hi, 0.0), axis=1)
    inbox = outside == 0.0
    worst = -float(outside[~inbox].min()) if (~inbox).any() else -np.inf
    if inbox.any():
        worst = max(worst, float(trimesh.proximity.signed_distance(mesh, points[inbox]).max()))
    return worst


def geom_contact_gaps(xml_path, model, q: np.ndarray, root: np.ndarray, frame: np.ndarray, link: np.ndarray,
                      points: np.ndarray):
    """Distance of contact points to the surface of their link's MJCF geoms posed by MuJoCo.

    Args:
        xml_path, model, q (T, D), root (T, 4, 4): as in :func:`geom_depths`
        frame: (N,) frame of each contact; link: (N,) its link index; points: (N, 3) world, metres
    Returns:
        (N,) metres, NaN for a link without geoms; None when MuJoCo is not installed.
    """
    posed = _PosedGeoms.load(xml_path, model, spacing=None)
    if posed is None:
        return None
    out = np.full(len(frame), np.nan)
    d = posed.data
    for t in np.unique(frame):
        posed.pose(q[t], root[t])
        for j in np.nonzero(frame == t)[0]:
            for g, _, _, tm in posed.by_link.get(int(link[j]), []):
                R, p = d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g]
                local = (points[j] - p) @ R
                dist = float(trimesh.proximity.closest_point(tm, local[None])[1][0])
                out[j] = dist if np.isnan(out[j]) else min(out[j], dist)
    return out

def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def _table_depth(table, world: np.ndarray) -> float:
    """Depth of the points ``world`` (n, 3) under the table plane ``table`` (a height) or in an environment's
    solids."""
    if isinstance(table, (int, float)):
        return table - float(world[:, 2].min())
    from .ground import environment_point_depth

    return float(environment_point_depth(table, world).max())
