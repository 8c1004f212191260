"""The hand's generalised force at rest under contact forces (Eq. 5 without inertia), the forward-difference pose
batches of its numerical derivatives, and the weights of the per-frame merit (Liu 2009, :mod:`.synth`)."""

from __future__ import annotations

import numpy as np
import torch

from ._frame_geometry import exp_rot

__all__ = ["SETTLE_WEIGHT", "ELASTIC_WEIGHT", "TOUCH_WEIGHT", "torques"]

SETTLE_WEIGHT = 100.0
"""Weight of the soft no-slip rows of the first frame, N m per metre."""
ELASTIC_WEIGHT = 1000.0
"""l1 weight (per metre) of the Eq. 7 rows (and of non-penetration) in the merit and in elastic mode."""
TOUCH_WEIGHT = 1000.0
"""l1 weight (per metre) of the Eq. 6 rows in the merit and in elastic mode."""


def torques(hand, q, root, links, h, f, gravity=(0.0, 0.0, -9.81)) -> np.ndarray:
    """The generalised force the hand must produce to hold contact forces f at rest (Eq. 5 without inertia):
    ``n(q) + sum_i J_i(q, h_i)^T f_i``.

    hand: HandModel (float64); q: (B, D) rad; root: (B, 4, 4) T_world_hand; links: (H,) link indices; h: (B, H, 3)
    link-frame points, metres; f: (H, 3) or (B, H, 3) forces of the hand on the object, world, newtons.
    returns: (B, 6 + D): torque about the root origin (world, N m), force (world, N), joint torques (N m)
    """
    q = torch.as_tensor(np.asarray(q), dtype=torch.float64)
    root = torch.as_tensor(np.asarray(root), dtype=torch.float64)
    B, L = q.shape[0], hand.num_links
    # n(q) = sum_l J_l(com_l)^T (-m_l g): the links' weights enter as point forces at their centres of mass, so
    # one Jacobian pass gives gravity and contact terms together
    g = torch.as_tensor(gravity, dtype=torch.float64)
    w = (-hand.link_mass.double()[:, None] * g).expand(B, L, 3)
    pts = hand.link_com.double().expand(B, L, 3)
    idx = torch.arange(L)
    if len(links):
        fb = torch.as_tensor(np.broadcast_to(np.asarray(f), (B, len(links), 3)).copy(), dtype=torch.float64)
        w = torch.cat([fb, w], 1)
        pts = torch.cat([torch.as_tensor(np.asarray(h), dtype=torch.float64).expand(B, len(links), 3), pts], 1)
        idx = torch.cat([torch.as_tensor(np.asarray(links), dtype=torch.long), idx])
    u = hand.contact_torques(q, root, idx, pts, w)
    return u.numpy()


def _pose_batch(root: np.ndarray, q: np.ndarray, h: np.ndarray, eps: float, with_h: bool):
    """Base point plus one forward-difference perturbation per variable (root twist, q, and h when ``with_h``)."""
    D, H = q.shape[0], h.shape[0]
    nv = 6 + D + (3 * H if with_h else 0)
    Q = np.repeat(q[None], nv + 1, 0)
    Rt = np.repeat(root[None], nv + 1, 0)
    Hh = np.repeat(h[None], nv + 1, 0)
    E = exp_rot(eps * np.eye(3))
    for j in range(3):
        Rt[1 + j, :3, :3] = E[j] @ root[:3, :3]
        Rt[4 + j, j, 3] += eps
    Q[7:7 + D] += eps * np.eye(D)
    if with_h:
        Hh[7 + D:] += eps * np.eye(3 * H).reshape(3 * H, H, 3)
    return Q, Rt, Hh
