"""Per-frame hand-motion synthesis (Liu 2009, Sec. 5, Eqs. 5-8).

Given the planned contact forces F_k of frame k (:mod:`.plan`), :func:`synthesize_frame` moves the hand (joint
angles q, the free root's pose) and the contact points (h_i on the link, p_i on the object) so that the torques the
hand needs to hold those forces stay close to the equilibrium torques u_bar of the grasp:

    argmin_{q, root, h}  |u(q, root, h) - u_bar|^2 + prox        (Eq. 8 with u eliminated by Eq. 5)
    u = n(q) + sum_i J_i(q, h_i)^T f_i                           (Eq. 5 quasi-static; dynamics="full" adds
                                                                  M(q) q_ddot + C(q, q_dot))

``n(q)`` is :meth:`~torchhand.hand.HandModel.gravity_torques` (the sign of MuJoCo's ``qfrc_bias``), ``J_i`` the
point Jacobian with the root twist first (:func:`~torchhand.hand.dynamics.point_jacobian`, ``wrt_root=True``) and
``f_i`` the force of the hand on the object (so ``-f_i`` acts on the hand and the actuators supply ``+J^T f``).
Generalised forces are ``(torque about the root origin, force, joint torques)``, world frame, N m and N.

Constraints (linearised at every iteration)
    * Eq. 6, contacts stay together: the hand point of a contact is parametrised by its position s in [0, 1] along
      its link capsule's axis, ``h = c(s) - r n`` (the capsule point facing the object, n the object's outward normal
      at c, the capsule standing in for Liu's ellipsoid segment), and the capsule must touch the object,
      ``sd(c(s)) = r`` (SDF grid of the object; smooth at the object's edges, where ``sd(p) = 0`` is not). The object
      point is eliminated: ``p = E(s_k)^-1 E(q) h`` (projected onto the mesh by the caller).
    * Eq. 7, no slip: with ``d = E(q) h_i^{k-1} - E(s_k) p_i^{k-1}`` minus the same offset at k-1 (``v_r dt``), a
      static contact keeps both tangential components of d zero (rolling allowed: the normal component and the
      contact point are free). A contact that slid into frame k, or whose planned force lies on the cone boundary
      (``|f.t1| + |f.t2| >= 0.97 mu f.n``), may slide along the tangential force the hand applies:
      ``d . t3 = 0``, ``-d . f_t <= 0`` (t3 normal to f_t in the tangent plane).
    * joint limits; ``|q - q^{k-1}| <= dq_max`` per frame; root speed and angular speed bounds; ``|s - s^{k-1}|``
      times the axis length at most ``h_step`` per frame;
    * non-penetration (addition (a) of docs/manipulation.md): capsules of different fingers within 1 cm keep
      their axis distance ``>= r_a + r_b - margin`` (``hand.collision_pairs``); 8 points along every link capsule's
      axis, and each contact's axis point c(s), keep ``sd >= r - margin`` from the object and ``z - r >= table - margin`` from the table; an axis point already
      deeper at the start of the frame may not go deeper;
    * contacts added by the planner (Sec. 4.3) that are not active yet approach their object point with a receding
      slack ``gap <= d_j (t_e - t) / (t_e - t_a)`` (linear; t_a the frame of addition, t_e its first active frame);
      from t_e on they obey Eq. 6 (Eq. 7 from the frame after). The caller checks that such a contact touches at
      t_e (``FrameResult.gap``) before its force is kept (:mod:`.manipulate`).

Solver (Sec. 5.3 says SQP): Gauss-Newton on ``|r|^2`` with ``r = u - u_bar`` over x = (root twist, q, s): the
Jacobian of r analytic (``dJ^T f / dq`` from the joint axes, :mod:`.torque_derivs`, with the point Jacobians and the
link poses from the same single kinematics pass), or, with ``SynthSettings(derivatives="finite")``, by batched
forward differences of :func:`torques` (one batched call per iteration); each step is a dense convex QP
(Gauss-Newton Hessian, the proximal terms and Levenberg-Marquardt damping) solved by a Goldfarb-Idnani dual
active-set method (:func:`dense_qp`); a step that raises the l1 merit ``|r|^2 + prox + w |violation|_1`` is rejected
and the damping raised; an infeasible step goes to elastic mode (l1 slacks on the equalities and on the
receding-slack rows of approaching contacts).

Convergence, within a work budget of Gauss-Newton iterations (``max_iters``, then ``POLISH_STEPS`` more):
    * a trial step that raises the merit by breaking the curved constraints gets a second-order correction (one
      least-norm step back onto them, :func:`._frame_solve._trial`); without it the constraints' curvature rejected nearly every
      useful step and the iterates crept;
    * the merit is stationary when an accepted step changes it by at most ``merit_tol`` (1e-9) of it or moves no
      variable by more than ``step_tol`` of its step scale, or when no step however short lowers it;
    * the frame has **converged** when its merit is stationary and the constraints hold within ``VIOL_TOL``
      (1e-9 m);
    * then undamped steps polish the point without comparing merits (merit differences are rounding there), each
      shorter than 0.95 times the one before, until a step moves no variable by more than ``POLISH_TOL`` (1e-9) of
      its step scale; a polish that stops contracting keeps its point only if the merit stayed within
      ``merit_tol``.
    A frame that does not converge keeps its last point and says so (``FrameResult.converged``, stats.json
    ``sqp_converged``). After the iterations, least-norm restoration steps onto the constraints.

Deviations from the paper (documented choices)
    * Proximal terms ``eps |q - q^{k-1}|^2`` (and on the root and on s): fingers that carry no force have tiny gravity
      torques and are otherwise undetermined, and along a line contact (a capsule lying on a face) the contact point
      could drift without any motion of the hand. They are 0.05 N m per rad and 0.5 N per m of the root's
      translation: with 1e-3, converged frames moved the fingers by up to 0.7 rad to shift the hand's weight under
      the wrist (the wrist's six rows dominate |u - u_bar|^2), along directions so weakly determined that a 1e-9 m
      change of the object's path changed the motion by 0.7 rad.
    * Hand contacts are static (``sliding=False``, the default): with Liu's rule (a planned force on the cone
      boundary may slide) converged frames slid the contacts to where the grasp could not hold the object.
    * The forces are held at their planned world values during the iterations (B_i(p_i) is not re-linearised); the
      caller re-projects them onto the final contact positions (addition (c), :mod:`.manipulate`).
    * ``settle`` (the first frame): Eq. 7 as weighted residual rows, so the grasp's contacts can settle onto the
      capsule model.
    * The ablation ``objective="pose"`` minimises ``|q - q^{k-1}|^2`` (root twist included) instead of the torque
      deviation (Sec. 6 "without the objective").
    * The objective's torques are quasi-static by default (``dynamics="quasi-static"``; Liu calls the inertial
      term "relatively small"); with ``dynamics="full"`` Eq. 5's inertial term enters the objective linearised at
      the frame's start, by backward differences (:mod:`._frame_dynamics`). The stored torques are Eq. 5 in full.
      The root is a free 6-DOF body, not an arm.

Conventions: metres, seconds, radians, newtons; column-vector 4x4 transforms; contact normals point into the
object; f is the force of the hand on the object.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputValueError
from ._frame_dynamics import frame_inertia
from ._frame_geometry import _axis_param, _tangents, exp_rot, rotvec
from ._frame_linearise import FrameSetup, linearise
from ._frame_solve import VIOL_TOL, _apply_step, _iterate
from ._frame_qp import _solve, dense_qp  # noqa: F401  (_solve: the tests reach it here)
from ._frame_torques import (ELASTIC_WEIGHT, SETTLE_WEIGHT, TOUCH_WEIGHT,  # noqa: F401  (their home until moved)
                             _pose_batch, torques)
from .torque_derivs import (
    TreeOrder,
    tree_order,
    tree_state,
)

__all__ = ["SynthSettings", "HandFrame", "FrameResult", "SynthContext", "synthesize_frame", "torques", "dense_qp",
           "rotvec", "exp_rot"]


@dataclass(frozen=True)
class SynthSettings:
    """Settings of :func:`synthesize_frame`.

    objective: "torque" (Eq. 8, |u - u_bar|^2) or "pose" (the ablation: |q - q^{k-1}|^2)
    joint_speed: |dq/dt| bound, rad/s (the checker's 8 rad/s; 0.267 rad per frame at 30 fps)
    root_speed: root translation speed bound, m/s; root_rate: root angular speed bound, rad/s
    prox_q: weight of (q - q^{k-1}) and of the root rotation in the residual, N m per rad
    prox_x: weight of the root translation in the residual, N m per metre
    prox_h: weight of the contact's axis motion (s - s^{k-1}) times the axis length in the residual, N m per metre:
        along a line contact (a capsule lying on a face) the contact point can move without any motion of the hand,
        so its drift is damped
    h_step: bound on that motion per frame, metres (ten times more at the settling first frame)
    margin: allowed penetration of capsules into the object and the table, metres
    max_iters: the work budget, Gauss-Newton iterations per frame (three times as many at the settling first frame)
    merit_tol: converged when an accepted step changes the l1 merit by at most this fraction of it
    step_tol: converged when an accepted step moves every variable by at most this fraction of its step scale
        (0.05 rad per joint, 0.02 rad and 5 mm of the root, 2 mm along a contact's capsule axis)
    boundary: a planned force with |f.t1| + |f.t2| >= boundary mu f.n lies on the cone boundary (may slide)
    slip_speed: a contact whose material points move apart tangentially faster than this slides, m/s
    voxel: SDF grid spacing of the object, metres
    derivatives: "analytic" (the Jacobian of the torques and the point Jacobians from one kinematics pass,
        :mod:`.torque_derivs`) or "finite" (batched forward differences of :func:`torques`, step 1e-7; kept for
        comparison)
    dynamics: the torques of the objective: "quasi-static" (u = n(q) + sum J^T f, the default) or "full" (Eq. 5's
        M(q) q_ddot + C(q, q_dot) added by backward differences, :mod:`._frame_dynamics`; a finger that carries no
        force then swings under the constant torque u_bar, and did so at the speed limit, 0.27 rad a frame, on
        liu-lift). The stored torques are Eq. 5 in full either way
    sliding: hand contacts may slide (Liu's rule: a planned force on the cone boundary, ``boundary``, or material
        points that moved apart faster than ``slip_speed``); off by default, every hand contact static (Eq. 7's
        no-slip rows): with converged frames, sliding contacts slid to where the grasp could no longer hold the
        object (docs/manipulation.md, "Converged frames"). The table's contacts slide either way
    """

    objective: str = "torque"
    joint_speed: float = 8.0
    root_speed: float = 1.0
    root_rate: float = 6.0
    prox_q: float = 0.05
    prox_x: float = 0.5
    prox_h: float = 30.0
    h_step: float = 1e-3
    margin: float = 5e-4
    max_iters: int = 30
    merit_tol: float = 1e-9
    step_tol: float = 1e-6
    boundary: float = 0.97
    slip_speed: float = 1e-3
    voxel: float = 0.001
    derivatives: str = "analytic"
    dynamics: str = "quasi-static"
    sliding: bool = False

    def __post_init__(self):
        if self.objective not in ("torque", "pose"):
            raise InputValueError(f"objective: expected 'torque' or 'pose', got {self.objective!r}")
        if not isinstance(self.sliding, bool):
            raise InputValueError(f"sliding: expected True or False, got {self.sliding!r}")
        if self.dynamics not in ("full", "quasi-static"):
            raise InputValueError(f"dynamics: expected 'full' or 'quasi-static', got {self.dynamics!r}")
        if self.derivatives not in ("analytic", "finite"):
            raise InputValueError(f"derivatives: expected 'analytic' or 'finite', got {self.derivatives!r}")
        for name in ("joint_speed", "root_speed", "root_rate", "prox_q", "prox_x", "prox_h", "h_step", "voxel",
                     "slip_speed", "merit_tol", "step_tol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputValueError(f"{name}: expected a positive number, got {v!r}")
        if isinstance(self.max_iters, bool) or not isinstance(self.max_iters, int) or self.max_iters < 1:
            raise InputValueError(f"max_iters: expected an integer >= 1, got {self.max_iters!r}")


@dataclass(frozen=True, eq=False)
class HandFrame:
    """The hand and its contacts at one frame (NumPy, float64; H hand contacts).

    q: joint angles, (D,), radians; root: wrist pose T_world_hand, (4, 4), metres
    h: contact points on their links, link frame, (H, 3), metres
    p: contact points on the object, object frame, (H, 3), metres
    """

    q: np.ndarray
    root: np.ndarray
    h: np.ndarray
    p: np.ndarray


@dataclass(frozen=True, eq=False)
class FrameResult:
    """What :func:`synthesize_frame` returns.

    frame: the synthesized :class:`HandFrame`
    objective: the final |r|^2 (without the proximal terms), (N m)^2 (pose objective: rad^2)
    iterations: Gauss-Newton iterations; converged: the last step was below ``step_tol``
    violation: largest constraint violation left, metres
    gap: distance of each contact's link capsule from the object (its Eq. 6 residual), (H,), metres
    """

    frame: HandFrame
    objective: float
    iterations: int
    converged: bool
    violation: float
    gap: np.ndarray | None = None


class SynthContext:
    """What stays fixed over a motion: the hand (float64, CPU), the object SDF, the capsule-axis samples (8 per link:
    with 4, a link lying along a box edge sank 2.2 mm between samples on the pushed test turn; 8 cost no measurable
    time on box-turn 6:66), the table and the equilibrium torques u_bar (6 + D,)."""

    def __init__(self, hand, mesh, u_bar: np.ndarray, fps: float, table_height: float | None,
                 gravity=(0.0, 0.0, -9.81), settings: SynthSettings | None = None, samples_per_link: int = 8):
        from ..geometry.sdf import SDFGrid

        self.settings = settings or SynthSettings()
        self.hand = hand.to("cpu", torch.float64)
        self.sdf = SDFGrid.from_mesh(mesh, self.settings.voxel, progress=False, dtype=torch.float64)
        self.u_bar = np.asarray(u_bar, dtype=np.float64)
        self.dt = 1.0 / float(fps)
        self.table = table_height
        self.gravity = tuple(float(g) for g in gravity)
        r = self.hand.capsule_radius.numpy()
        a, b = self.hand.capsule_a.numpy(), self.hand.capsule_b.numpy()
        links = np.flatnonzero(r > 0)
        s = np.linspace(0.0, 1.0, samples_per_link)
        self.ax_link = np.repeat(links, samples_per_link)
        self.ax_local = (a[links, None] + s[None, :, None] * (b - a)[links, None]).reshape(-1, 3)
        self.ax_radius = r[self.ax_link]
        self.cap_a, self.cap_b, self.cap_r = a, b, r
        lim = self.hand.joint_limits.numpy()
        self.q_lo, self.q_hi = lim[:, 0], lim[:, 1]
        self.pairs_np = self.hand.collision_pairs.cpu().long().numpy().reshape(-1, 2)
        self.pairs = self.pairs_np
        self.D = self.hand.num_joints
        self.order = tree_order(self.hand)

    def sdf_with_grad(self, points: np.ndarray):
        """Signed distance (P,) and its gradient (P, 3) of the object at object-frame points (P, 3), metres: the
        grid's trilinear kernel called directly (the values of :meth:`~torchhand.geometry.sdf.SDFGrid.query_with_grad`
        without its autograd wrapper and checks, which cost a fifth of a query at this size)."""
        sd, grad = self.sdf.query_with_grad_unchecked(torch.from_numpy(points)[None])
        return sd[0].numpy(), grad[0].numpy()

    def object_normals(self, points: np.ndarray) -> np.ndarray:
        """Outward unit normals of the object at object-frame points (P, 3): the SDF grid's gradient, continuous
        across edges (a blend of the faces' normals within a voxel of an edge, inside their normal cone)."""
        _, g = self.sdf.query_with_grad(torch.as_tensor(np.asarray(points, dtype=np.float64))[None])
        g = g[0].numpy()
        return g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-12)

    def torques(self, q, root, links, h, f) -> np.ndarray:
        """u = n(q) + sum_i J_i^T f_i for a batch: q (B, D), root (B, 4, 4), links (H,), h (B, H, 3), f (H, 3)
        world newtons; returns (B, 6 + D)."""
        return torques(self.hand, q, root, links, h, f, self.gravity)


# ------------------------------------------------------------------------------------------------ one frame
def _qp_step(L, lm, damp, base, nv, C_box, project=False):
    """The step: Gauss-Newton QP damped by ``lm`` (Levenberg-Marquardt, scaled by the per-iteration step sizes
    ``base``), or, with ``project``, the least-norm step onto the constraints."""
    if project:
        Hm, g = damp.copy(), np.zeros(nv)
    else:
        Hm = 2 * (L.Jr.T @ L.Jr + L.Jp.T @ L.Jp) + lm * damp
        g = 2 * (L.Jr.T @ L.r + L.Jp.T @ L.pr)
    lo, hi = np.maximum(L.vlo, -4 * base), np.minimum(L.vhi, 4 * base)
    C = np.concatenate([L.C, C_box], 0)
    d = np.concatenate([L.d, hi, -lo])
    dx, status, _ = dense_qp(Hm, g, L.A, L.b, C, d)
    if status != 0:                                   # elastic mode: l1-penalised slacks on the equalities
        A, b = L.A, L.b                         # and on the receding-slack rows (the first m_app of C)
        m, ma = A.shape[0], L.m_app
        ne = nv + 2 * m + ma
        He = np.zeros((ne, ne))
        He[:nv, :nv] = Hm
        He[nv:, nv:] = 1e-9 * np.eye(2 * m + ma)
        ge = np.concatenate([g, L.w, L.w, np.full(ma, ELASTIC_WEIGHT)])
        Ae = np.concatenate([A, np.eye(m), -np.eye(m), np.zeros((m, ma))], 1)
        Ce = np.zeros((C.shape[0] + 2 * m + ma, ne))
        Ce[:C.shape[0], :nv] = C
        Ce[np.arange(ma), nv + 2 * m + np.arange(ma)] = -1.0
        Ce[C.shape[0]:, nv:] = -np.eye(2 * m + ma)
        de = np.concatenate([d, np.zeros(2 * m + ma)])
        dx = dense_qp(He, ge, Ae, b, Ce, de)[0][:nv]
    # the box bounds (joint limits, speeds) hold exactly whatever the subproblem's status: a failed elastic
    # solve may return a step outside them
    return np.clip(dx, lo, hi)


def synthesize_frame(ctx: SynthContext, prev: HandFrame, start: HandFrame, links: np.ndarray, forces: np.ndarray,
                     active: np.ndarray, pose: np.ndarray, pose_prev: np.ndarray, normals_prev: np.ndarray,
                     slide: np.ndarray, approach: dict, closing: np.ndarray, settle: bool = False,
                     before: HandFrame | None = None) -> FrameResult:
    """Eq. 8 at one frame (module docstring). returns: :class:`FrameResult` (its ``frame.p`` is None: the caller
    projects E(q) h onto the object).

    prev: the hand at frame k-1 (for Eq. 7, the velocity bounds and the proximal terms)
    start: the initial guess (e.g. prev moved rigidly with the object); h of inactive contacts is kept
    links: (H,) link index of each hand contact; forces: planned F_k, (H, 3), world newtons (0 where inactive)
    active: (H,) bool, contacts that carry force at k
    pose, pose_prev: object poses T_world_object at k and k-1, (4, 4)
    normals_prev: object-frame normals into the object at p^{k-1}, (H, 3)
    slide: (H,) bool, contacts that may slide (slid into k, or force on the cone boundary)
    approach: contact -> gap bound sigma_j(k), metres, for added contacts not active yet
    closing: (H,) bool, added contacts active from this frame on (no Eq. 7 rows yet)
    settle: Eq. 7 as weighted residual rows (``SETTLE_WEIGHT``) instead of constraints: the first frame, where the
        grasp's contacts settle onto the capsule model and a rigid no-slip grasp could not close their gaps
    before: the hand at frame k-2 (q, root) for the inertial term's backward differences (None: ``prev``, the hand
        at rest before k-1)

    The hand point of a contact on a link with a capsule is parametrised by its position s in [0, 1] along the
    capsule's axis: ``h = c(s) - r n``, c(s) the axis point and n the object's outward normal there (the capsule
    point facing the object); Eq. 6 is then ``sd(c(s)) = r`` (the capsule touches the object), which is smooth at
    the object's edges where ``sd(p) = 0`` is not. Links without a capsule keep their point.
    """
    st = ctx.settings
    hand, D, H = ctx.hand, ctx.D, len(links)
    N = 6 + D
    nv = N + H
    links = np.asarray(links, dtype=np.int64)
    Rs, os_ = pose[:3, :3], pose[:3, 3]
    dt = ctx.dt
    ca, cb, cr = ctx.cap_a[links], ctx.cap_b[links], ctx.cap_r[links]
    seg = cb - ca
    seg_len = np.maximum(np.linalg.norm(seg, axis=-1), 1e-9)
    movable = (cr > 0) & np.array([i not in approach for i in range(H)], dtype=bool)
    # Eq. 7's offset at k-1 (zero when the contact was exact)
    x_prev_mat = _points(hand, prev.q, prev.root, links, prev.h)
    d0 = x_prev_mat - (prev.p @ pose_prev[:3, :3].T + pose_prev[:3, 3])
    y_prev = prev.p @ Rs.T + os_                               # object material points at k
    n_w = normals_prev @ Rs.T
    f_t = forces - (forces * n_w).sum(-1, keepdims=True) * n_w
    f_use = np.where(active[:, None], forces, 0.0)
    w_q, w_x = st.prox_q, st.prox_x
    wq = 1.0 if st.objective == "pose" else w_q
    wx = 10.0 if st.objective == "pose" else w_x
    R_prev = prev.root[:3, :3]
    s_prev = _axis_param(ca, seg, prev.h)
    base = np.concatenate([[0.02] * 3, [0.005] * 3, [0.05] * D, 0.002 / seg_len])
    s_step = st.h_step * (10.0 if settle else 1.0) / seg_len  # settling may move h onto the capsule's facing side

    analytic = st.derivatives == "analytic"
    # per-frame constants of the rows below: the proximal Jacobian, each contact's tangents (Eq. 7) and, for a
    # contact that may slide, the direction of its tangential force and the tangent normal to it
    Jp_const = np.diag(np.concatenate([np.full(3, wq), np.full(3, wx), np.full(D, wq), st.prox_h * seg_len]))
    tangents = [_tangents(n_w[i]) for i in range(H)]
    slide_dir = {}
    for i in range(H):
        ft = f_t[i]
        if slide[i] and np.linalg.norm(ft) > 1e-9:
            fhat = ft / np.linalg.norm(ft)
            slide_dir[i] = (fhat, np.cross(n_w[i], fhat))
    eye_nv = np.eye(nv)
    C_box = np.concatenate([eye_nv, -eye_nv], 0)                    # the step bounds' rows of every QP

    floor: dict = {}                                     # non-penetration floors, fixed at the frame's start

    inertia = None
    if st.dynamics == "full" and st.objective == "torque":
        inertia = frame_inertia(hand, start, prev, before if before is not None else prev, dt)
    setup = FrameSetup(H=H, inertia=inertia, Jp_const=Jp_const, N=N, R_prev=R_prev, Rs=Rs, active=active, analytic=analytic,
                       approach=approach, ca=ca, closing=closing, cr=cr, ctx=ctx, d0=d0, dt=dt, f_use=f_use,
                       floor=floor, hand=hand, links=links, movable=movable, nv=nv, os_=os_, prev=prev,
                       s_prev=s_prev, s_step=s_step, seg=seg, seg_len=seg_len, settle=settle, slide_dir=slide_dir,
                       st=st, start=start, tangents=tangents, wq=wq, wx=wx, y_prev=y_prev)

    damp = np.diag(1.0 / base ** 2)

    x = (start.q.copy(), start.root.copy(), _axis_param(ca, seg, start.h))
    max_iters = st.max_iters * (3 if settle else 1)        # the first frame starts farther from feasibility
    x, L, it, converged = _iterate(setup, x, linearise(setup, *x), max_iters,
                                   lambda L_, lm, project=False: _qp_step(L_, lm, damp, base, nv, C_box, project),
                                   base, N)
    for _ in range(4):                                    # restore the constraints (least-norm steps)
        if L.viol <= VIOL_TOL:
            break
        x = _apply_step(x, _qp_step(L, 0.0, damp, base, nv, C_box, project=True), N)
        L = linearise(setup, *x)
    q, root, _ = x
    return FrameResult(frame=HandFrame(q=q, root=root, h=L.h, p=None), objective=L.objective, iterations=it,
                       converged=converged and L.viol <= VIOL_TOL, violation=L.viol, gap=L.gap)


_TREES: dict = {}


def _tree(hand) -> TreeOrder:
    """The NumPy tree of ``hand`` (cached per model object)."""
    key = id(hand)
    hit = _TREES.get(key)
    if hit is None or hit[0]() is not hand:
        hit = (weakref.ref(hand), tree_order(hand))
        if len(_TREES) > 64:
            _TREES.clear()
        _TREES[key] = hit
    return hit[1]


def _points(hand, q, root, links, local) -> np.ndarray:
    """World positions of link-frame points, (P, 3)."""
    if len(links) == 0:
        return np.zeros((0, 3))
    T = tree_state(_tree(hand), np.asarray(q, dtype=np.float64), np.asarray(root, dtype=np.float64)).T
    Tl = T[np.asarray(links)]
    return np.einsum("pij,pj->pi", Tl[:, :3, :3], local) + Tl[:, :3, 3]
