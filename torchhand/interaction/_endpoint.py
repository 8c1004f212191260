"""The endpoint references of a perturbation trial (Kry & Pai 2006 §4.2, design note decision 10): the vertical
endpoint stiffness kG = 1 / G_zz from G = J C J^T (torchhand's point Jacobian of the planar finger of
:mod:`torchhand.interaction.mujoco_truth`) and the effective endpoint mass from MuJoCo's mass matrix and Jacobian.

Used by :mod:`torchhand.interaction.perturb`. Units: metres, newtons, kilograms, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mujoco_truth import LINKS, ROOT_HEIGHT, _mujoco, planar_finger_mjcf

__all__ = ["EndpointReference", "endpoint_compliance", "endpoint_reference"]


@dataclass(frozen=True, eq=False)
class EndpointReference:
    """Vertical endpoint stiffness and mass at a posture.

    G: effective endpoint compliance J C J^T at the contact point, (3, 3), m/N (torchhand's Jacobian)
    kG: 1 / G_zz, N/m (lateral motion free); kG_held: (G_xz^-1)_zz, N/m (the tip held sideways; the planar finger's
    G has no y stiffness, so the x-z block is inverted); mass: 1 / (e_z^T J M^-1 J^T e_z), kg (MuJoCo's M and J)
    """

    G: np.ndarray
    kG: float
    kG_held: float
    mass: float


def _finger_hand(compliance):
    """The planar finger with joint compliances (4,), rad/(N m), as a HandModel (through a temporary MJCF file)."""
    import tempfile
    from pathlib import Path

    from ..hand.model import HandModel

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "planar_finger.xml"
        path.write_text(planar_finger_mjcf(compliance))
        return HandModel.from_mjcf(path)


def endpoint_compliance(theta, point_local, compliance) -> np.ndarray:
    """G = J C J^T, (3, 3), m/N, at the distal link's point ``point_local`` (3,) for joint angles ``theta`` (4,)
    and joint compliances (4,), with torchhand's point Jacobian (root compliance 0: the forearm is held)."""
    import torch

    from torchhand.kernels.contact_lcp import effective_compliance

    from ..hand.dynamics import point_jacobian

    c = np.asarray(compliance, dtype=np.float64)
    hand = _finger_hand(c).to(device="cpu", dtype=torch.float64)
    q = torch.as_tensor(np.asarray(theta, dtype=np.float64))[None]
    root = torch.eye(4, dtype=torch.float64)[None].clone()
    root[0, 2, 3] = ROOT_HEIGHT
    link = torch.tensor([hand.link_index(LINKS[3])])
    p = torch.as_tensor(np.asarray(point_local, dtype=np.float64))[None]
    J = point_jacobian(hand, q, link, p, root, wrt_root=True)[:, 0]          # (1, 3, 6 + 4)
    C = torch.cat([torch.zeros(1, 6, dtype=torch.float64), torch.from_numpy(c)[None]], -1)
    return effective_compliance(J, C).numpy()[0]


def endpoint_reference(model, data, theta, point_local, compliance) -> EndpointReference:
    """:class:`EndpointReference` at ``theta`` (4,): G and kG from torchhand, the endpoint mass from MuJoCo
    (``model``/``data`` of :func:`perturbation_mjcf`, whose first four DOFs are the finger's)."""
    mujoco = _mujoco()
    G = endpoint_compliance(theta, point_local, compliance)
    Gxz = G[np.ix_([0, 2], [0, 2])]
    d = mujoco.MjData(model)
    d.qpos[:4] = theta
    mujoco.mj_forward(model, d)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, M, d.qM)
    distal = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, LINKS[3])
    p_world = d.xpos[distal] + d.xmat[distal].reshape(3, 3) @ np.asarray(point_local)
    jacp = np.zeros((3, model.nv))
    mujoco.mj_jac(model, d, jacp, None, p_world, distal)
    Jf, Mf = jacp[:, :4], M[:4, :4]
    inv_mass = float(Jf[2] @ np.linalg.solve(Mf, Jf[2]))
    return EndpointReference(G=G, kG=float(1.0 / G[2, 2]), kG_held=float(np.linalg.inv(Gxz)[1, 1]),
                             mass=float(1.0 / inv_mass))
