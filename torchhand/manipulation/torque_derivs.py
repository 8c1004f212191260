"""Analytic first derivatives of the static generalised force ``u = n(q) + sum_i J_i(q, h_i)^T f_i`` of a floating
hand (the torques of Liu 2009 Eq. 5 at rest, :func:`.synth.torques`), and point Jacobians, for one configuration.

Coordinates are those of :func:`torchhand.hand.dynamics.point_jacobian` with ``wrt_root=True``: x = (w, v, q),
w the root's world rotation about the root origin, v the root origin's world translation, q the joints; u = (torque
about the root origin (world, N m), force (world, N), joint torques (N m or N)). Every force f_i (world, held
fixed) acts at a link-fixed point p_i; the links' weights ``-m_l g`` at their centres of mass give n(q).

A motion of variable k moves a link-fixed point p with ``dp = a_k x (p - o_k)`` (hinge k above p's link, o_k on
its axis; for the root rotation a_k = e and o_k the root origin), ``dp = a_k`` (slide k or the root translation),
and turns the joint axes below it with ``da = a_k x a``. For a hinge j above p, ``tau_j = a_j . ((p - o_j) x f)``:

    * k above j (or k = j): a_j, p and o_j move rigidly about a_k, and tau_j would not change if f turned with
      them, so ``d tau_j = -a_j . ((p - o_j) x (a_k x f)) = -J_j(p) . (a_k x f)``, J_j(p) the point Jacobian's
      column j (``a_j x (p - o_j)``; ``a_j`` for a slide j, where ``tau_j = a_j . f`` gives the same formula);
      a slide k (or the root translation) above j translates them and changes nothing;
    * k below j (between j and p): only p moves, ``d tau_j = a_j . (J_k(p) x f) = -J_k(p) . (a_j x f)`` (zero for
      a slide j);
    * the root rows: ``d (r x f) = dp x f`` with r = p minus the root origin, which the root rotation also turns.

With ``M[j, k] = sum_i J_j(p_i) . (a_k x f_i)`` the joint block is ``-above[k, j] hinge[k] M[j, k] -
strictly_above[j, k] hinge[j] M[k, j]``: two dense products over all joints and points at once, no loop over
joints. Conventions: metres, radians, newtons, column-vector 4x4 transforms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from torchhand.kernels import kinematics as _kin

__all__ = ["TreeOrder", "TreeState", "point_jacobian", "static_torques", "torques_and_derivatives", "tree_order",
           "tree_state"]


@dataclass(frozen=True, eq=False)
class TreeOrder:
    """A hand's kinematic tree in NumPy (float64) for single-configuration kinematics, and its joint ancestry.

    above: above[k, j] is True when joint k moves joint j's axis and anchor, or k = j, (D, D) bool (joints of one
        link count in application order: an earlier joint moves the later ones)
    hinge: (D,) bool, True for hinge joints, False for slide joints
    support: support[l, j] is True when joint j moves link l, (L, D) bool
    parent: (L,) parent link, -1 for the root; offset: (L, 4, 4) parent -> link at q = 0, metres
    axis, anchor: (D, 3) joint axis (unit) and a point on it in the joint's link frame, metres
    slot_links, slot_joints: for k = 0, 1, ...: the links that have a k-th joint and those joints, tuples of (m_k,)
    levels: link indices by depth, root level first, tuple of (n_k,); joint_parent: (D,) parent link of each
        joint's link, -1 for joints on the root link
    rod_k, rod_k2: (D, 3, 3) Rodrigues' [a]x and a a^T - I of each joint (zero for slide joints)
    axis_anchor: (D, 4, 2) the homogeneous axis (w = 0) and anchor (w = 1) of each joint, link frame
    mass: (L,) link masses, kg; com: (L, 3) link centres of mass, link frame, metres
    """

    above: np.ndarray
    hinge: np.ndarray
    support: np.ndarray
    parent: np.ndarray
    offset: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray
    slot_links: tuple
    slot_joints: tuple
    levels: tuple
    joint_parent: np.ndarray
    rod_k: np.ndarray
    rod_k2: np.ndarray
    axis_anchor: np.ndarray
    mass: np.ndarray
    com: np.ndarray


@dataclass(frozen=True, eq=False)
class TreeState:
    """World kinematics of one configuration (NumPy, float64).

    T: link poses T_world_link, (L, 4, 4), metres
    axis: world unit axis of every joint, (D, 3); anchor: a world point on it, (D, 3), metres
    origin: the root origin ``root[:3, 3]``, (3,), metres
    """

    T: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray
    origin: np.ndarray


def tree_order(hand) -> TreeOrder:
    """:class:`TreeOrder` of ``hand``'s chain and link inertials (any dtype or device; copied to NumPy float64)."""
    c = hand.chain
    support = c.support.cpu().numpy().astype(bool)
    joint_link = c.joint_link.cpu().numpy()
    parent = c.link_parent.cpu().numpy()
    link_joints = c.link_joints.cpu().numpy()
    D = joint_link.shape[0]
    slot = np.zeros(D, dtype=np.int64)
    for lj in link_joints:
        for s, j in enumerate(lj):
            if j < D:
                slot[j] = s
    pl = parent[joint_link]
    above = np.where(pl[None, :] >= 0, support[np.maximum(pl, 0)].T, False)          # [k, j]: k moves j's parent
    above |= (joint_link[:, None] == joint_link[None, :]) & (slot[:, None] <= slot[None, :])
    hinge = c.joint_type.cpu().numpy() == _kin.JOINT_HINGE

    def arr(t, dtype=np.float64):
        return t.detach().cpu().numpy().astype(dtype)

    a, anchor = arr(c.joint_axis), arr(c.joint_anchor)
    hg = hinge[:, None, None]
    aa = np.zeros((D, 4, 2))
    aa[:, :3, 0], aa[:, :3, 1], aa[:, 3, 1] = a, anchor, 1.0
    return TreeOrder(above=above, hinge=hinge, support=support, parent=parent, offset=arr(c.link_offset),
                     axis=a, anchor=anchor,
                     slot_links=tuple(arr(t, np.int64) for t in c.slot_links),
                     slot_joints=tuple(arr(t, np.int64) for t in c.slot_joints),
                     levels=tuple(arr(t, np.int64) for t in c.levels), joint_parent=pl,
                     rod_k=_cross_matrix(a) * hg, rod_k2=(a[:, :, None] * a[:, None, :] - np.eye(3)) * hg,
                     axis_anchor=aa, mass=arr(hand.link_mass), com=arr(hand.link_com))


def tree_state(tree: TreeOrder, q: np.ndarray, root: np.ndarray) -> TreeState:
    """Link poses and joint axes of one configuration: q (D,) radians / metres, root (4, 4) T_world_hand (the
    model of :mod:`torchhand.kernels.kinematics`, evaluated in NumPy: at a single configuration it costs a few
    dozen array operations instead of a batched kernel's fixed overhead)."""
    q = np.asarray(q, dtype=np.float64)
    root = np.asarray(root, dtype=np.float64)
    D, L = q.shape[0], tree.parent.shape[0]
    # joint transforms (D, 4, 4): hinge Trans(anchor) Rot(axis, q) Trans(-anchor), slide Trans(axis q) (Rodrigues)
    a, c = tree.axis, tree.anchor
    Jm = np.zeros((D, 4, 4))
    Rj = np.eye(3) + np.sin(q)[:, None, None] * tree.rod_k + (1.0 - np.cos(q))[:, None, None] * tree.rod_k2
    Jm[:, :3, :3] = Rj
    Jm[:, :3, 3] = c - (Rj @ c[:, :, None])[:, :, 0] + (~tree.hinge)[:, None] * a * q[:, None]
    Jm[:, 3, 3] = 1.0
    loc = tree.offset.copy()
    ax_an = np.empty((D, 4, 2))                               # axis and anchor in the joint link's parent frame
    for links, joints in zip(tree.slot_links, tree.slot_joints):
        ll = loc[links]
        ax_an[joints] = ll @ tree.axis_anchor[joints]
        loc[links] = ll @ Jm[joints]
    T = np.empty((L, 4, 4))
    for depth, level in enumerate(tree.levels):
        T[level] = (root if depth == 0 else T[tree.parent[level]]) @ loc[level]
    Tp = np.where((tree.joint_parent < 0)[:, None, None], root[None], T[np.maximum(tree.joint_parent, 0)])
    W = Tp @ ax_an
    return TreeState(T=T, axis=W[:, :3, 0], anchor=W[:, :3, 1], origin=root[:3, 3].copy())


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis of broadcastable (..., 3) arrays (np.cross's axis handling costs more than the
    product at these sizes)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _joint_columns(order: TreeOrder, st: TreeState, links: np.ndarray, x: np.ndarray) -> np.ndarray:
    """d x / d q of world points x (P, 3) on ``links`` (P,): (P, D, 3), zero for joints that do not move them
    (evaluated for the (point, joint) pairs of the support only: a point moves with the few joints above its link)."""
    P, D = x.shape[0], st.axis.shape[0]
    pi, ji = np.nonzero(order.support[links])                                # the supporting pairs
    a = st.axis[ji]
    cols = np.zeros((P, D, 3))
    cols[pi, ji] = np.where(order.hinge[ji][:, None], _cross(a, x[pi] - st.anchor[ji]), a)
    return cols


def point_jacobian(order: TreeOrder, st: TreeState, links, x: np.ndarray) -> np.ndarray:
    """Jacobian of link-fixed points at world positions x (P, 3) on ``links`` (P,) with respect to (w, v, q):
    (P, 3, 6 + D), the layout of :func:`torchhand.hand.dynamics.point_jacobian` with ``wrt_root=True``."""
    links = np.asarray(links, dtype=np.int64)
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    P, D = x.shape[0], st.axis.shape[0]
    J = np.zeros((P, 3, 6 + D))
    r = x - st.origin
    J[:, 0, 1], J[:, 0, 2] = r[:, 2], -r[:, 1]                               # -[r]x
    J[:, 1, 0], J[:, 1, 2] = -r[:, 2], r[:, 0]
    J[:, 2, 0], J[:, 2, 1] = r[:, 1], -r[:, 0]
    J[:, :, 3:6] = np.eye(3)
    J[:, :, 6:] = _joint_columns(order, st, links, x).transpose(0, 2, 1)
    return J


def _cross_matrix(v: np.ndarray) -> np.ndarray:
    """[v]x (..., 3, 3) of v (..., 3)."""
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return K - np.swapaxes(K, -1, -2)


def torques_and_derivatives(order: TreeOrder, st: TreeState, links, h: np.ndarray, f: np.ndarray,
                            gravity=(0.0, 0.0, -9.81)):
    """u = n(q) + sum_i J_i^T f_i and its first derivatives at one configuration (module docstring).

    order: :func:`tree_order` of the hand (its link masses and centres of mass give n(q)); st: :func:`tree_state`
    of the configuration; links: (H,) link of each contact; h: (H, 3) link-frame points, metres;
    f: (H, 3) world forces of the hand on the object, newtons (held fixed).
    returns: (u (6 + D,), du_dx (6 + D, 6 + D) the derivative with respect to (w, v, q) with the points fixed on
        their links, du_dp (H, 6 + D, 3) the derivative with respect to each contact's world point with the
        configuration fixed)
    """
    links = np.asarray(links, dtype=np.int64).reshape(-1)
    H = links.shape[0]
    D = st.axis.shape[0]
    N = 6 + D
    f = np.asarray(f, dtype=np.float64).reshape(H, 3)
    u, F, Jc, r, Jd = _static_force(order, st, links, h, f, gravity)
    G = _cross(st.axis[None], F[:, None, :])                               # a_k x f_i, (P, D, 3)
    M = Jd @ G.transpose(1, 0, 2).reshape(D, -1).T                           # J_j(p_i) . (a_k x f_i)
    hk = order.hinge.astype(np.float64)
    strict = order.above & ~np.eye(D, dtype=bool)
    dq = np.zeros((N, N))
    dq[6:, 6:] = -(order.above.T * hk[None, :]) * M - (strict * hk[:, None]) * M.T
    JxF = _cross(Jc, F[:, None, :]).sum(0)                                 # sum_i J_k(p_i) x f_i, (D, 3)
    dq[6:, 0:3] = JxF
    dq[0:3, 6:] = JxF.T
    dq[0:3, 0:3] = (_cross_matrix(F) @ _cross_matrix(r)).sum(0)
    du_dp = np.zeros((H, N, 3))
    if H:
        du_dp[:, 0:3, :] = -_cross_matrix(f)
        sup = order.support[links] & order.hinge[None, :]                   # (H, D)
        du_dp[:, 6:, :] = -G[:H] * sup[:, :, None]
    return u, dq, du_dp


def _static_force(order: TreeOrder, st: TreeState, links: np.ndarray, h, f: np.ndarray, gravity):
    """u and the pieces its derivatives reuse: (u (6 + D,), F (P, 3) the forces, Jc (P, D, 3) their points' joint
    columns, r (P, 3) their points relative to the root origin, Jd (D, P * 3) = Jc flattened per joint); P = H + L,
    the H contacts first, then the L links' weights at their centres of mass."""
    H = links.shape[0]
    D = st.axis.shape[0]
    T = st.T
    L = T.shape[0]
    mass, com = order.mass, order.com
    g = np.asarray(gravity, dtype=np.float64)
    h = np.asarray(h, dtype=np.float64).reshape(H, 3)
    # every force at its world point: the H contacts, then the L links' weights at their centres of mass
    all_links = np.concatenate([links, np.arange(L)])
    local = np.concatenate([h, com], 0)
    Tl = T[all_links]
    x = np.einsum("pij,pj->pi", Tl[:, :3, :3], local) + Tl[:, :3, 3]
    F = np.concatenate([f, -mass[:, None] * g[None]], 0)                     # (P, 3)
    Jc = _joint_columns(order, st, all_links, x)                             # (P, D, 3)
    r = x - st.origin
    u = np.zeros(6 + D)
    u[0:3] = _cross(r, F).sum(0)
    u[3:6] = F.sum(0)
    Jd = Jc.transpose(1, 0, 2).reshape(D, -1)                                # (D, P * 3)
    u[6:] = Jd @ F.reshape(-1)
    return u, F, Jc, r, Jd


def static_torques(order: TreeOrder, st: TreeState, links, h: np.ndarray, f: np.ndarray,
                   gravity=(0.0, 0.0, -9.81)) -> np.ndarray:
    """u = n(q) + sum_i J_i^T f_i at one configuration, (6 + D,): the first output of
    :func:`torques_and_derivatives` (the same arithmetic) without the derivatives. Arguments as there."""
    links = np.asarray(links, dtype=np.int64).reshape(-1)
    f = np.asarray(f, dtype=np.float64).reshape(links.shape[0], 3)
    return _static_force(order, st, links, h, f, gravity)[0]
