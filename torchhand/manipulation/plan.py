"""Contact-force planning from a grasp (Liu 2009, Sec. 3 Stage 1 and Sec. 4, Eqs. 1-4, Sec. 4.3).

**Scope.** This is the planning half of Liu's main loop (Fig. 2). Alone (:func:`plan_motion`) the grasp is
**rigid**: hand contacts stay where the snapped grasp puts them, fixed in the object frame, and move with the object,
so "the contact positions p^{k-1} solved by the previous iteration" are always the grasp's and no hand contact
slides. The manipulation loop (:mod:`.manipulate`) steps the same machinery frame by frame (``_start``, ``_step``)
and, between frames, moves the contacts to the synthesized frame k-1 (points, normals, transported tangents; a
contact that slid into frame k takes the sliding ray at t = k from ``_Contacts.slide``) and the hand surface that
new contacts are chosen from (``_Geometry.move_hand``).

Stage 1 (preprocessing)
    Initial contacts: the snapped grasp's (:mod:`.snap`). F_{-1} = argmin sum_i |f_i|^2 subject to Eq. 1 at frame 0
    and the limits (the resolution of Liu's equilibrium torques, docs/manipulation.md); it is lambda^{k-1} of the
    first window. When frame 0 itself is infeasible, contacts are added there as below.

Window loop, for k = 0 .. T-1
    1. Eq. 4 over t = k .. k+n-1 (n = ``window``, 6; shorter at the end of the motion), assembled by
       :func:`torchhand.kernels.force_plan.assemble_window_qp` and solved by
       :func:`torchhand.kernels.convex_qp.solve_convex_qp`: hand contacts at ``object_pose[t] @ p_i`` with
       transported tangents (``R_t t1_i``, so bases do not flip), static pyramids, normal force <= ``f_max``
       (30 N); table contacts from :func:`torchhand.scene._contacts.environment_contacts` (at most 8 per frame,
       farthest-point thinned), static or sliding as the object motion says (the sliding ray points along the
       table's velocity relative to the object's point, i.e. against the object's), lambda >= 0 only; the required
       wrench from :func:`torchhand.synthesis.problem.required_wrench` (less the scene's ``external_wrench``, which
       acts on the object: the contacts supply the rest). F_k = B_k lambda_k is kept; F_{k+1} ..
       are re-planned by the next window.
    2. Infeasible (Sec. 4.3): the per-frame LPs (:func:`~torchhand.kernels.force_plan.assemble_frame_lps`,
       :func:`torchhand.solvers._qpth.lp_feasible` with ``method="admm"``) find the first infeasible frame t_a. Hand contacts
       are ordered by decreasing |f_i|; for contact i on link S_i the new hand point is the hand surface sample
       (at the grasp pose) closest to h_i that is not on S_i, paired with its closest object point (normal from
       that face). Pairs are added one at a time, each active from t_a on, and the LPs re-tested; the loop stops
       when every frame of the window is feasible. No set that makes the window feasible:
       :class:`GraspUnsuitable` with the frame and the wrench deficit.

Readings and deviations (documented choices; the paper is silent or the rigid grasp forces them)
    * "The contact forces" that order the contacts do not exist when Eq. 4 is infeasible: they are taken from the
      least-squares wrench fit at t_a, ``argmin |W lambda - w|^2 + 1e-6 sum_i |f_i|^2`` subject to the limits
      (the forces the contacts would push with, saturated ones first). Its residual ``w - W lambda`` is the
      **wrench deficit** reported by :class:`GraspUnsuitable`.
    * New contacts go to the first infeasible frame of the window. Liu adds them at the window's last frame
      because earlier frames were made feasible by earlier windows; with rigid contacts that first infeasible frame
      *is* the last one, except in the first window (and Stage 1), whose frames are all new.
    * A candidate's link must hold no contact yet (Liu: only "not on S_i"), so every addition brings a new link;
      once the closest candidates of all contacts are taken, the next round cycles again with the added ones.
    * When added contacts become active. Liu (Sec. 4.3, Sec. 5): new contacts go to "the last frame of the window",
      and the synthesis enforces Eq. 6 "with a receding slack that reaches zero at the frame when the contact is
      established"; a contact therefore carries force only from the frame it touches, and the frames before it are
      its approach. Read that way, three rules hold in the manipulation loop (``geo.reach_step`` set):
      (1) a candidate must be reachable in the frames left before it carries force, t_a - k (:func:`_candidate`,
      :func:`_reach`: its gap at most ``TOUCH_TOL`` plus what the hand can close at the synthesis' speed bounds
      while the active contacts keep still; a link moved only by the wrist, such as a metacarpal of the default
      hand, reaches next to nothing); the cycle over the contacts skips unreachable candidates and takes the reachable
      one nearest the highest-force contact; (2) with t_a = k (the window's first frame is infeasible, which Liu
      calls the rare case where the synthesis' new contact positions break the plan) only a touching candidate
      can be added, otherwise the grasp is unsuitable, as Liu deems it; (3) the loop (:mod:`.manipulate`) checks
      after the synthesis that an added contact touches (within ``TOUCH_TOL``) at its first active frame, and
      otherwise plans and synthesizes that frame again with the contact pending one frame more.
      Planning alone (:func:`plan_motion`, rigid grasp) has no hand motion and keeps Liu's plain choice.
    * Added contacts keep their first position (no synthesis moves them onto the hand yet) and stay to the end.
    * The per-frame LP status and the QP status are recorded per frame; a QP that fails although every LP is
      feasible (a solver failure, not an infeasible motion) keeps the LP's witness forces for that frame and its
      status says so.

Conventions: world z-up, metres, seconds, newtons; contact normals point into the object; f = B lambda is the force
of the hand (or the table) on the object; wrench = (force, torque about the COM), world.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputValueError
from ..kernels.convex_qp import solve_convex_qp
from ..kernels.force_plan import FrameLPs, WindowQP, assemble_frame_lps, assemble_window_qp
from ..kernels.frames import tangent_frame
from ..kernels.status import SolverStatus
from .grasp import Grasp, check_grasp_hand, grasp_hand
from .snap import SNAP_TOL, hand_surface_in_object, snap_grasp, signed_distance

__all__ = ["PlanSettings", "ForcePlan", "WindowRecord", "GraspUnsuitable", "plan_motion", "plan_forces"]

_CONVERGED = int(SolverStatus.CONVERGED)


class GraspUnsuitable(RuntimeError):
    """The grasp cannot realise the object motion (Liu 2009, Sec. 4.3: no set of added contacts makes a window
    feasible). Not a :class:`~torchhand.errors.TorchhandError` (the input is valid; the motion is not achievable):
    the ``manipulate`` command reports it with exit code 1.

    frame: the infeasible frame; deficit: the wrench the contacts cannot produce there, (6,), N and N m (force,
    torque about the COM, world); contacts: hand contact links tried (including added ones)
    window: the first frame of the window that failed (the frames before it were planned); partial: what was done
    before it, set by the caller that did it (:func:`torchhand.manipulation.manipulate` sets the
    :class:`~torchhand.manipulation.manipulate.ManipulationResult` of frames ``0 .. window - 1``, or None when
    no frame was synthesized)
    """

    def __init__(self, frame: int, deficit: np.ndarray, contacts: tuple, window: int | None = None):
        self.frame, self.deficit, self.contacts = int(frame), np.asarray(deficit, dtype=np.float64), tuple(contacts)
        self.window = int(frame if window is None else window)
        self.partial = None
        f, t = np.linalg.norm(self.deficit[:3]), np.linalg.norm(self.deficit[3:])
        super().__init__(f"the grasp cannot realise the motion at frame {self.frame}: wrench deficit "
                         f"{f:.3f} N and {t:.4f} N m with contacts {', '.join(self.contacts) or '-'} (force "
                         f"{np.array2string(self.deficit[:3], precision=3)} N, torque "
                         f"{np.array2string(self.deficit[3:], precision=4)} N m)")


@dataclass(frozen=True)
class PlanSettings:
    """Settings of :func:`plan_motion`.

    window: frames per planning window, n (Liu: 6; 5-10 work)
    max_contact_force: normal-force limit of each hand contact, newtons (Liu: 30 N)
    added_contacts: add contacts when a window is infeasible (Sec. 4.3); False: infeasible = unsuitable
    max_added: most contacts added over the whole motion
    mass: object mass override, kg (inertia scaled with it), or None (the scene's)
    friction: hand-object friction override, or None (the scene's)
    snap_tol: snap tolerance for a grasp without contacts, metres
    max_env_contacts: table contacts kept per frame
    keep_problems: keep every window QP and per-frame LP in ``ForcePlan.records`` (for tests and references)
    qp_solver: "dense" (one problem at a time in NumPy / LAPACK, :func:`torchhand.solvers._dense.solve_qp_dense`; the
        default, about twice as fast per frame on a CPU) or "kernel" (the batched torch kernel,
        :func:`torchhand.kernels.convex_qp.solve_convex_qp`: ADMM warm-started, then the interior point)
    """

    window: int = 6
    max_contact_force: float = 30.0
    added_contacts: bool = True
    max_added: int = 8
    mass: float | None = None
    friction: float | None = None
    snap_tol: float = SNAP_TOL
    max_env_contacts: int = 8
    keep_problems: bool = False
    qp_solver: str = "dense"

    def __post_init__(self):
        if self.qp_solver not in ("dense", "kernel"):
            raise InputValueError(f"qp_solver: expected 'dense' or 'kernel', got {self.qp_solver!r}")
        if isinstance(self.window, bool) or not isinstance(self.window, int) or self.window < 1:
            raise InputValueError(f"window: expected an integer >= 1, got {self.window!r}")
        for name in ("max_contact_force", "snap_tol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputValueError(f"{name}: expected a positive number, got {v!r}")
        for name in ("mass", "friction"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputValueError(f"{name}: expected a positive number or None, got {v!r}")


@dataclass(frozen=True, eq=False)
class WindowRecord:
    """One solved problem (kept with ``keep_problems``): frame k, the window QP (B = 1) and its result's
    objective (of 1/2 z^T Q z + p^T z, without ``qp.offset``) and status; or, for an LP test, ``lps`` (B = 1) and
    the per-frame verdicts ``feasible (n,)``."""

    frame: int
    qp: WindowQP | None = None
    objective: float = float("nan")
    status: int = -1
    lps: FrameLPs | None = None
    feasible: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class ForcePlan:
    """Planned contact forces over a motion (T frames, K slots: the hand contacts in order of creation, then the
    table slots). NumPy, float64.

    forces: F_t, force of each contact on the object, (T, K, 3), world, newtons (0 where inactive)
    lam: basis coefficients lambda, (T, K, 4), newtons
    points: contact points, (T, K, 3), world, metres; normals: into the object, (T, K, 3), world
    mask: the slot is active at frame t, (T, K) bool
    hand: hand slots, (K,) bool (False: table); links: (K,) link names ("table" for table slots)
    hand_local: hand contact points in their link frame, (K, 3), metres (0 for table slots)
    object_local: hand contact points on the object, object frame, (K, 3), metres (0 for table slots)
    added: the slot is an added contact (Sec. 4.3) and active at t, (T, K) bool
    added_at: frame an added slot starts, (K,) int (-1: initial or table); added_from: slot it was generated from,
        (K,) int (-1)
    f_init: F_{-1} of Stage 1, (K, 3), newtons
    com: centre of mass, (T, 3); wrench: the wrench planned for, (T, 6), N and N m: the required wrench, less a
        deficit within ``BALANCE_ALLOWANCE`` where the contacts cannot produce it exactly
    status: window-QP status of each frame's window, (T,) int8 (:class:`~torchhand.kernels.status.SolverStatus`)
    objective: Eq. 4's value sum_t sum_i |f_i^t - f_i^(t-1)|^2 of each frame's window, (T,), N^2
    timings: seconds: ``stage1_s``, ``plan_s`` (total), ``per_frame_s`` (list of T), ``added_s``
    records: the kept problems (:class:`WindowRecord`), () unless ``keep_problems``
    """

    forces: np.ndarray
    lam: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    mask: np.ndarray
    hand: np.ndarray
    links: tuple
    hand_local: np.ndarray
    object_local: np.ndarray
    added: np.ndarray
    added_at: np.ndarray
    added_from: np.ndarray
    f_init: np.ndarray
    com: np.ndarray
    wrench: np.ndarray
    status: np.ndarray
    objective: np.ndarray
    timings: dict = field(default_factory=dict)
    records: tuple = ()

    @property
    def T(self) -> int:
        return int(self.forces.shape[0])

    @property
    def num_added(self) -> int:
        return int((self.added_at >= 0).sum())


# ------------------------------------------------------------------------------------------------ contact state
@dataclass
class _Contacts:
    """Hand contacts (object frame) and the candidates for new ones (mutable working state of one planning run)."""

    link: list           # link index per contact
    h: list              # link-local hand point (3,)
    p: list              # object-frame point (3,)
    n: list              # object-frame normal into the object (3,)
    t1: list             # object-frame first tangent (3,)
    start: list          # first active frame
    source: list         # slot it was generated from (-1)
    h_obj: list          # the hand point in the object frame at the grasp pose (3,)
    slide: dict = field(default_factory=dict)   # contact -> world velocity of its hand point relative to the object
                                                # point at k-1, for contacts sliding into frame k (hand synthesis)


def _normal_frame(n: np.ndarray) -> np.ndarray:
    t1, _ = tangent_frame(torch.as_tensor(n, dtype=torch.float64)[None])
    return t1[0].numpy()


class _Geometry:
    """Everything fixed over a run: the object's motion and required wrench, the table contacts, the hand surface at
    the grasp pose (object frame) and the object mesh."""

    def __init__(self, scene, grasps, hands, settings: PlanSettings):
        from ..scene import environment_contacts
        from ..synthesis.problem import _thin_env, required_wrench

        obj = scene.object
        mass = float(settings.mass if settings.mass is not None else obj.mass)
        inertia = torch.tensor(np.array(obj.inertia), dtype=torch.float64) * (mass / float(obj.mass))
        pose = scene.object_pose.double()
        com, wrench = required_wrench(pose, torch.tensor(np.array(obj.com), dtype=torch.float64), mass, inertia,
                                      scene.gravity.double(), scene.fps, external=scene.external_wrench)
        self.T = int(pose.shape[0])
        self.pose = pose.numpy()
        self.com, self.wrench = com.numpy(), wrench.numpy()
        self.wrench_required = self.wrench.copy()        # self.wrench: as planned (within the deficit allowance)
        self.weight = mass * float(torch.linalg.vector_norm(scene.gravity.double()))
        self.extent = float(np.max(obj.mesh.extents))
        self.mu = float(settings.friction if settings.friction is not None else scene.friction)
        self.mu_env = float(scene.environment.friction)
        env = _thin_env(environment_contacts(scene), settings.max_env_contacts)
        self.env_points = env.points.double().numpy()                       # (T, E, 3)
        self.env_mask = env.mask.numpy()
        self.env_slide = -env.sliding_velocity.double().numpy()             # table point relative to object point
        self.E = int(self.env_mask.shape[1])
        self.mesh = obj.mesh
        # one or two hands; links are numbered across them: hand j's link l is link_offset[j] + l
        grasps = [grasps] if isinstance(grasps, Grasp) else list(grasps)
        self.hands = list(hands) if isinstance(hands, (list, tuple)) else [hands]
        self.hand = self.hands[0]
        self.sides = [g.side for g in grasps]
        self.link_offset = np.cumsum([0] + [h.num_links for h in self.hands])
        self.sample_link = np.concatenate([h.sample_link.cpu().numpy() + o for h, o in zip(self.hands,
                                                                                          self.link_offset)])
        self.sample_local = np.concatenate([h.sample_points.detach().cpu().double().numpy() for h in self.hands])
        self.sample_hand = np.concatenate([np.full(h.sample_link.numel(), j) for j, h in enumerate(self.hands)])
        self.q_now = [np.asarray(g.q, dtype=np.float64) for g in grasps]
        self.wrist_now = [np.asarray(g.wrist_in_object, dtype=np.float64) for g in grasps]
        self.samples = np.zeros((len(self.sample_link), 3))
        self.link_pose = np.zeros((int(self.link_offset[-1]), 4, 4))
        for j in range(len(self.hands)):
            self._pose_hand(j)
        self._moved: dict = {}
        # Reachability of added contacts (set by the manipulation loop, which moves the hand; None: planning alone,
        # a rigid grasp, where any link may take a contact): the joint step per frame the synthesis allows, rad.
        self.reach_step: float | None = None

    def move_hand(self, q: np.ndarray, wrist_in_object: np.ndarray, j: int = 0) -> None:
        """Hand j's current pose (joint angles (D,), wrist in the object frame (4, 4)): new contacts (Sec. 4.3)
        are chosen from the hand surface there (computed when a contact is added)."""
        self._moved[j] = (np.asarray(q, dtype=np.float64), np.asarray(wrist_in_object, dtype=np.float64))

    def _pose_hand(self, j: int) -> None:
        hand, q, w = self.hands[j], self.q_now[j], self.wrist_now[j]
        self.samples[self.sample_hand == j] = hand_surface_in_object(hand, q, w)
        lo, hi = self.link_offset[j], self.link_offset[j + 1]
        self.link_pose[lo:hi] = (torch.as_tensor(w) @ hand.forward_kinematics(torch.as_tensor(q)[None])[0]).numpy()

    def _refresh(self) -> None:
        for j, (q, w) in self._moved.items():
            self.q_now[j], self.wrist_now[j] = q, w
            self._pose_hand(j)
        self._moved = {}

    def hand_of(self, link: int) -> int:
        """The hand (index into ``hands``) of a numbered link."""
        return int(np.searchsorted(self.link_offset, link, side="right") - 1)

    def link_name(self, link: int) -> str:
        """A numbered link's name; with two hands ``<side>/<link>`` (the result files' convention)."""
        j = self.hand_of(link)
        name = self.hands[j].link_names[link - self.link_offset[j]]
        return name if len(self.hands) == 1 else f"{self.sides[j]}/{name}"


def _initial_contacts(geo: _Geometry, grasps) -> _Contacts:
    c = _Contacts([], [], [], [], [], [], [], [])
    for j, grasp in enumerate([grasps] if isinstance(grasps, Grasp) else grasps):
        _, _, nrm = signed_distance(geo.mesh, grasp.contact_object)
        for name, h, p, n_out in zip(grasp.contact_links, grasp.contact_hand, grasp.contact_object, nrm):
            _add(c, geo, geo.link_offset[j] + geo.hands[j].link_index(name), h, p, -n_out, 0, -1)
    return c


def _add(c: _Contacts, geo: _Geometry, link: int, h, p, n, start: int, source: int) -> None:
    geo._refresh()
    n = np.asarray(n, dtype=np.float64)
    n = n / np.linalg.norm(n)
    T = geo.link_pose[link]
    c.link.append(int(link)), c.h.append(np.asarray(h, dtype=np.float64)), c.p.append(np.asarray(p, dtype=np.float64))
    c.n.append(n), c.t1.append(_normal_frame(n)), c.start.append(int(start)), c.source.append(int(source))
    c.h_obj.append(T[:3, :3] @ np.asarray(h, dtype=np.float64) + T[:3, 3])


TOUCH_TOL = 1e-3
"""An added contact touches when its hand point (its link capsule, in the synthesis) is within this of the object,
metres: half the checker's 2 mm contact-hand bound."""
REACH_FACTOR = 1.0
"""Fraction of the linearised approach (:func:`_reach`) an added contact may count on. An overestimate costs a
deferral, never a force before touching (:mod:`.manipulate`)."""


def _candidate(c: _Contacts, geo: _Geometry, i: int, frames: int | None = None, k: int = 0):
    """Sec. 4.3: the hand sample closest to contact i's hand point on a link of the same hand holding no contact,
    and its closest object point with that face's inward normal; None when every such link holds a contact.

    frames: the frames the hand has to close the new contact's gap (t_e - k, the synthesis of frames k+1 .. t_e;
    0 when the contact must carry force at the current frame). With the manipulation loop's reachability
    (``geo.reach_step`` set) the candidate must be reachable in them (:func:`_reach`); among the reachable links
    the one closest to h_i is taken (Liu: the closest point not on S_i)."""
    geo._refresh()
    free = ~np.isin(geo.sample_link, np.array(c.link)) & (geo.sample_hand == geo.hand_of(c.link[i]))
    if not free.any():
        return None
    d = np.linalg.norm(geo.samples - c.h_obj[i], axis=1)
    d[~free] = np.inf
    if geo.reach_step is None or frames is None:
        s = int(np.argmin(d))
        _, p, n_out = signed_distance(geo.mesh, geo.samples[s:s + 1])
        return int(geo.sample_link[s]), geo.sample_local[s], p[0], -n_out[0]
    # the closest sample of every free link, nearest link first
    links = np.unique(geo.sample_link[free])
    best = np.array([int(np.flatnonzero(geo.sample_link == l)[np.argmin(d[geo.sample_link == l])]) for l in links])
    best = best[np.argsort(d[best], kind="stable")]
    x = geo.samples[best]
    _, p, n_out = signed_distance(geo.mesh, x)
    gap = np.linalg.norm(p - x, axis=1)
    reach = _reach(c, geo, best, (p - x) / np.maximum(gap, 1e-12)[:, None], max(int(frames), 0), k)
    ok = np.flatnonzero(gap <= TOUCH_TOL + reach)
    if not len(ok):
        return None
    j = int(ok[0])
    s = int(best[j])
    return int(geo.sample_link[s]), geo.sample_local[s], p[j], -n_out[j]


def _reach(c: _Contacts, geo: _Geometry, samples: np.ndarray, direction: np.ndarray, frames: int,
           k: int) -> np.ndarray:
    """How far the hand can move each hand-surface sample along ``direction`` (P, 3), object frame, in ``frames``
    frames while the contacts active at frame k stay where they are, metres (P,).

    Linearised at the current pose, one small LP per sample (HiGHS): the largest ``g . J v`` over a per-frame joint
    step v with ``J_c v = 0`` (the active contacts' point Jacobians: they keep still, Eq. 7 without rolling) and
    ``|v_j|`` within the synthesis' per-frame bound ``geo.reach_step`` and the joint's room to its limits divided by
    ``frames``; J is the sample's Jacobian (3, D, object frame), g the direction. The samples are of one hand, and
    only that hand's active contacts are held. The sample closes
    ``REACH_FACTOR`` times ``frames`` times that maximum. The wrist is held: it follows the object and the holding
    contacts, and counting on its turn let a linearised estimate "reach" across the object with whole fingers. A
    link moved only by the wrist (a metacarpal of the default hand) reaches nothing; a link whose finger holds
    contacts further out reaches little. (An earlier estimate scaled the least-norm direction by the first
    per-frame bound it met; on liu-lift at 2.5 kg it found no candidate reachable and the grasp was judged
    unsuitable, while this one adds ring_proximal in time.)"""
    from scipy.optimize import linprog

    P = len(samples)
    out = np.zeros(P)
    if frames <= 0 or not P:
        return out
    which = int(geo.sample_hand[samples[0]])             # the candidates are one hand's (_candidate)
    hand, q, w, off = geo.hands[which], geo.q_now[which], geo.wrist_now[which], geo.link_offset[which]
    D = hand.num_joints
    act = [j for j in range(len(c.link)) if c.start[j] <= k and geo.hand_of(c.link[j]) == which]
    links = np.concatenate([geo.sample_link[samples], np.array([c.link[j] for j in act], dtype=np.int64)]) - off
    local = np.concatenate([geo.sample_local[samples], np.array([c.h[j] for j in act]).reshape(-1, 3)])
    J = hand.point_jacobian(torch.as_tensor(q)[None], torch.as_tensor(links), torch.as_tensor(local),
                            torch.as_tensor(w)[None], wrt_root=True)[0].numpy()[:, :, 6:]    # (P + A, 3, D)
    Jc = J[P:].reshape(-1, D)
    lim = hand.joint_limits.numpy()
    lo = np.maximum(-geo.reach_step, np.minimum((lim[:, 0] - q) / frames, 0.0))
    hi = np.minimum(geo.reach_step, np.maximum((lim[:, 1] - q) / frames, 0.0))
    bounds = list(zip(lo, hi))
    eq = dict(A_eq=Jc, b_eq=np.zeros(len(Jc))) if len(Jc) else {}
    for s in range(P):
        res = linprog(-(J[s].T @ direction[s]), bounds=bounds, method="highs", **eq)
        if res.status == 0 and -res.fun > 1e-12:
            out[s] = REACH_FACTOR * frames * float(-res.fun)
    return out


# ------------------------------------------------------------------------------------------------ window problems
def _window_arrays(c: _Contacts, geo: _Geometry, k: int, n: int, settings: PlanSettings):
    """Per-window inputs of the force_plan kernels (B = 1): points, normals, com, mu, wrench, mask, hand, sliding,
    tangent."""
    H, E = len(c.link), geo.E
    M = H + E
    ts = np.arange(k, k + n)
    R, o = geo.pose[ts, :3, :3], geo.pose[ts, :3, 3]
    pts = np.zeros((n, M, 3))
    nrm = np.zeros((n, M, 3))
    tan = np.zeros((n, M, 3))
    slide = np.zeros((n, M, 3))
    mask = np.zeros((n, M), dtype=bool)
    if H:
        P, N, T1 = np.stack(c.p), np.stack(c.n), np.stack(c.t1)
        pts[:, :H] = np.einsum("tij,hj->thi", R, P) + o[:, None]
        nrm[:, :H] = np.einsum("tij,hj->thi", R, N)
        tan[:, :H] = np.einsum("tij,hj->thi", R, T1)
        mask[:, :H] = ts[:, None] >= np.array(c.start)[None]
        for i, v in c.slide.items():
            slide[0, i] = v
    if E:
        pts[:, H:] = geo.env_points[ts]
        nrm[:, H:] = (0.0, 0.0, 1.0)
        tan[:, H:] = (1.0, 0.0, 0.0)
        slide[:, H:] = geo.env_slide[ts]
        mask[:, H:] = geo.env_mask[ts]
    mu = np.array([geo.mu] * H + [geo.mu_env] * E)
    hand = np.array([True] * H + [False] * E)
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)[None]  # noqa: E731
    return dict(points=t(pts), normals=t(nrm), com=t(geo.com[ts]), mu=t(mu), wrench=t(geo.wrench[ts]),
                mask=torch.as_tensor(mask)[None], hand=torch.as_tensor(hand)[None],
                f_max=float(settings.max_contact_force), sliding=t(slide), tangent=t(tan))


def plan_forces(c: _Contacts, geo: _Geometry, k: int, n: int, f_prev: np.ndarray, settings: PlanSettings,
                records: list | None = None, z_prev: np.ndarray | None = None, method: str = "admm"):
    """Solve Eq. 4 for the window t = k .. k+n-1 with the current contacts (no additions).

    f_prev: B^{k-1} lambda^{k-1} per slot, (M, 3), newtons (M = hand contacts + table slots).
    z_prev: the previous window's solution (z, lam, nu) as returned here, shifted by one frame into a warm start
    (primal and multipliers, :func:`_shift_warm`) when its slots are the same.
    method: the kernel's ``method``: "admm" (ADMM with its active-set polish, warm-started when possible; the
    default), "auto" (the kernel's choice: ADMM with a warm start, the interior point without), "ipm" (the
    interior point, cold; the fallback for thin feasible sets, where ADMM stalls or declares infeasibility too
    early) or "dense" (:func:`torchhand.solvers._dense.solve_qp_dense`: the same interior point and polish in NumPy /
    LAPACK for this one problem, far less overhead than the batched kernel at B = 1; the warm start is polished
    first, then starts the interior point; what it leaves undecided goes to the kernel).
    Returns (lambda (n, M, 4), basis (n, M, 3, 4), status, objective of Eq. 4 (with its constant), the args,
    the solution (z (4 M n,), lam (5 M n,), nu (6 n,)) for the next window's warm start).
    """
    args = _window_arrays(c, geo, k, n, settings)
    qp = assemble_window_qp(f_prev=torch.as_tensor(f_prev, dtype=torch.float64)[None], **args)
    M = args["points"].shape[2]
    warm = _shift_warm(z_prev, n, M) if method != "ipm" else None
    if method == "dense":
        from ..solvers._dense import solve_qp_dense

        res = solve_qp_dense(qp.Q, qp.p, qp.G, qp.h, qp.A, qp.b, warm_start=warm)
    else:
        res = solve_convex_qp(qp.Q, qp.p, qp.G, qp.h, qp.A, qp.b, warm_start=warm, method=method)
    status = int(res.status[0])
    obj = float(res.objective[0] + qp.offset[0])
    if records is not None:
        records.append(WindowRecord(frame=k, qp=qp, objective=float(res.objective[0]), status=status))
    lam = res.z[0].reshape(n, M, 4).clamp_min(0).numpy()
    return lam, qp.basis[0].numpy(), status, obj, args, (res.z[0].numpy(), res.lam[0].numpy(), res.nu[0].numpy())


def _shift_warm(z_prev, n: int, M: int):
    """The previous window's solution (z (n' 4 M,), lam (n' 5 M,), nu (n' 6,)), n' = n or n + 1, shifted by one
    frame into a warm start of window k's QP (B = 1): its frames k .. k+n'-2, the last one repeated when n' = n
    (the window did not shorten). Rows of :func:`~torchhand.kernels.force_plan.assemble_window_qp`: lam is
    (-lambda <= 0 per frame, then n^T B lambda <= f_max per frame), nu is Eq. 1 per frame. None when the slots
    changed (another M) or there is no previous window."""
    if z_prev is None:
        return None
    z, lam, nu = z_prev
    n_old = z.shape[0] // (4 * M) if M else 0
    if z.shape[0] != 4 * M * n_old or n_old not in (n, n + 1) or lam.shape[0] != 5 * M * n_old \
            or nu.shape[0] != 6 * n_old:
        return None

    def shift(v, per):                          # drop frame k-1; repeat the last frame when the window kept its n
        v = torch.as_tensor(v, dtype=torch.float64)
        return torch.cat([v[per:], v[-per:]]) if n_old == n else v[per:]

    lam_b, lam_f = lam[:4 * M * n_old], lam[4 * M * n_old:]
    return (shift(z, 4 * M)[None], torch.cat([shift(lam_b, 4 * M), shift(lam_f, M)])[None], shift(nu, 6)[None])


def _frame_feasible(c: _Contacts, geo: _Geometry, k: int, n: int, settings: PlanSettings,
                    records: list | None = None) -> tuple[np.ndarray, FrameLPs, torch.Tensor]:
    """Per-frame LP feasibility of the window (Eq. 4 without objective), the n LPs in one batch, decided by
    :func:`torchhand.solvers._qpth.lp_feasible` with ``method="admm"`` (the convex-QP kernel with Q = 0 on unit rows; feasible
    iff the witness's largest unit-row violation is below ``tol (1 + |h|_inf + |b|_inf)``, a bound that does not
    grow with the witness; undecided counts as infeasible).
    Returns (feasible (n,), lps, witness z (n, 4 M)).
    """
    from ..solvers._qpth import lp_feasible

    args = _window_arrays(c, geo, k, n, settings)
    lps = assemble_frame_lps(**args)
    G, h, A, b = (x.flatten(0, 1) for x in lps)
    res = lp_feasible(G, h, A, b, method="admm")
    feasible = res.feasible.numpy().copy()
    if records is not None:
        records.append(WindowRecord(frame=k, lps=lps, feasible=feasible))
    return feasible, lps, res.z


def _wrench_fit(c: _Contacts, geo: _Geometry, t: int, settings: PlanSettings):
    """Least-squares wrench fit at frame t: argmin |W lambda - w|^2 + 1e-6 sum |f|^2 s.t. the limits (the dense
    single-problem QP path; the batched kernel with ``qp_solver="kernel"``, as :func:`_qp`).
    Returns (forces (M, 3), deficit w - W lambda (6,))."""
    args = _window_arrays(c, geo, t, 1, settings)
    lps = assemble_frame_lps(**args)
    W, w = lps.A[0, 0], lps.b[0, 0]
    basis = assemble_window_qp(f_prev=args["points"].new_zeros(1, args["points"].shape[2], 3), **args).basis[0, 0]
    M = basis.shape[0]
    Bd = torch.block_diag(*basis.unbind(0)) if M else W.new_zeros(0, 0)
    zero = (basis.abs().sum(-2) == 0).reshape(-1).to(W.dtype)
    Q = 2 * (W.T @ W + 1e-6 * Bd.T @ Bd + torch.diag(zero))
    if settings.qp_solver == "kernel":
        res = solve_convex_qp(Q[None], (-2 * W.T @ w)[None], lps.G[0], lps.h[0])
    else:
        from ..solvers._dense import solve_qp_dense

        res = solve_qp_dense(Q[None], (-2 * W.T @ w)[None], lps.G[0], lps.h[0])
    lam = res.z[0].clamp_min(0)
    forces = (basis @ lam.reshape(M, 4, 1)).squeeze(-1)
    return forces.numpy(), (w - W @ lam).numpy()


def _add_contacts(c: _Contacts, geo: _Geometry, k: int, n: int, feasible: np.ndarray, settings: PlanSettings,
                  records: list | None) -> int:
    """Sec. 4.3 at window k whose per-frame LPs ``feasible (n,)`` are not all true. Returns the frames of the window
    that can be planned now: n, or, in the manipulation loop (``geo.reach_step`` set) when no reachable contact makes
    a later frame t_bad > k feasible yet, t_bad - k (the next windows, with the hand moved on, try again); raises
    GraspUnsuitable when no set makes the window's first infeasible frame feasible and that frame is k (or, planning
    alone, whenever the window stays infeasible)."""
    t_a = k + int(np.argmin(feasible))
    added = 0
    if settings.added_contacts:
        used = sum(1 for s in c.source if s >= 0)
        tried: set = set()
        while used + added < settings.max_added and not feasible.all():
            forces, _ = _wrench_fit(c, geo, t_a, settings)
            H = len(c.link)
            active = [i for i in range(H) if c.start[i] <= t_a]
            order = sorted(active, key=lambda i: -float(np.linalg.norm(forces[i])))
            progress = False
            for i in order:
                if i in tried or used + added >= settings.max_added:
                    continue
                tried.add(i)
                cand = _candidate(c, geo, i, t_a - k, k)
                if cand is None:
                    continue
                _add(c, geo, cand[0], cand[1], cand[2], cand[3], t_a, i)
                added += 1
                progress = True
                feasible, _, _ = _frame_feasible(c, geo, k, n, settings, records)
                if feasible.all():
                    break
            if not progress:
                break
    if not feasible.all():
        t_bad = k + int(np.argmin(feasible))
        if geo.reach_step is not None and t_bad > k:
            return t_bad - k
        _, deficit = _wrench_fit(c, geo, t_bad, settings)
        raise GraspUnsuitable(t_bad, deficit, tuple(geo.link_name(l) for l in c.link), window=k)
    return n


def _qp(c, geo, k, n, f_prev, settings, records, z_prev=None):
    """The window QP, by default by the dense single-problem solver (``method="dense"``,
    :func:`torchhand.solvers._dense.solve_qp_dense`: the previous window's solution polished when its slots are the
    same, else the interior point (started from it) and polish in NumPy / LAPACK; what that leaves undecided
    goes to the kernel's interior point, then ADMM). With ``PlanSettings(qp_solver="kernel")`` (for
    comparisons), the batched torch kernel: ADMM (warm-started from the previous
    window when its slots are the same), then the interior point when ADMM does not converge. The dense path
    keeps the continuity of the warm start (its polished active set) and meets the same CONVERGED test; it is
    about twice as fast per frame at B = 1 (the kernel's cost there is per-operation overhead).

    In the kernel path, ADMM goes first for speed and for the motion's continuity, no longer to work around the
    kernel: the interior point now meets the same CONVERGED test (complementarity row by row). The kernel's own choice
    (``method="auto"``: the interior point whenever there is no warm start) agrees with Clarabel as closely and
    gives the same box-turn motion to 3e-9 degrees, but on the test turn (box-turn frames 14-25, torque objective)
    its slightly different forces at frames 0-1 led the synthesis to contacts that cannot hold frame 2
    (docs/manipulation.md, "Solver notes")."""
    if settings.qp_solver == "dense":
        return plan_forces(c, geo, k, n, f_prev, settings, records, z_prev, method="dense")
    out = plan_forces(c, geo, k, n, f_prev, settings, records, z_prev, method="admm")
    if out[2] != _CONVERGED:
        out = plan_forces(c, geo, k, n, f_prev, settings, records, method="ipm")
    return out


BALANCE_ALLOWANCE = 5e-3
"""Largest wrench deficit a planned frame may keep (:func:`_allow_small_deficits`), relative to the object's weight
for the force and to its weight times its largest extent for the torque: half the independent checker's 1 %
balance bound. A soft fingertip's torsional friction over a 2 mm patch at 0.5 N, about 8e-4 N m, is eight times
the torque this allows for the 0.05 kg roll cylinder."""


def allowed_deficit(geo: _Geometry, d: np.ndarray) -> bool:
    """Whether a wrench deficit ``d`` (6,) (force, torque about the COM; N, N m) is within ``BALANCE_ALLOWANCE``."""
    return bool(np.linalg.norm(d[:3]) <= BALANCE_ALLOWANCE * geo.weight
                and np.linalg.norm(d[3:]) <= BALANCE_ALLOWANCE * geo.weight * geo.extent)


def _allow_small_deficits(c: _Contacts, geo: _Geometry, k: int, n: int, feasible: np.ndarray,
                          settings: PlanSettings) -> bool:
    """Frames whose contacts miss the required wrench by a deficit within ``BALANCE_ALLOWANCE`` are planned for the
    nearest wrench they can produce, ``w - d`` (the least-squares fit of :func:`_wrench_fit`), instead of adding
    contacts (a deviation from Liu's exact Eq. 1, where Sec. 4.3 would add a contact or give up). The case is a
    pinch: two point contacts cannot produce a torque about the line through them, and a pinch line that misses
    the centre of mass by half a millimetre (a grasp is snapped to 0.1 mm, the synthesis moves the contacts) asks
    for one. Real fingertips are soft and give such torques by friction over their contact patch; the point-contact
    model does not have it, so a deficit this small is left unbalanced (the checker allows twice as much). The
    frames' wrenches go back to the required ones at the next window. Returns True when every infeasible frame of
    the window was within the allowance (and its wrench was moved)."""
    fixes = []
    for j in np.flatnonzero(~feasible):
        _, d = _wrench_fit(c, geo, k + int(j), settings)
        if not allowed_deficit(geo, d):
            return False
        fixes.append((k + int(j), d))
    for t, d in fixes:
        geo.wrench[t] = geo.wrench_required[t] - d
    return True


def _solve(c, geo, k, n, f_prev, settings, records, z_prev=None):
    """Eq. 4 at window k, with contacts added when infeasible (after the deficit allowance,
    :func:`_allow_small_deficits`). Returns (lambda, basis, status, objective, args, z)."""
    H0 = len(c.link)
    geo.wrench[k:k + n] = geo.wrench_required[k:k + n]      # undo the allowance of earlier windows on these frames
    out = _qp(c, geo, k, n, _pad(f_prev, H0, geo.E), settings, records, z_prev)
    if out[2] == _CONVERGED:
        return out
    feasible, _, _ = _frame_feasible(c, geo, k, n, settings, records)
    if not feasible.all() and _allow_small_deficits(c, geo, k, n, feasible, settings):
        out = _qp(c, geo, k, n, _pad(f_prev, H0, geo.E), settings, records)
        if out[2] == _CONVERGED:
            return out
        feasible, _, _ = _frame_feasible(c, geo, k, n, settings, records)
    if not feasible.all():
        n = _add_contacts(c, geo, k, n, feasible, settings, records)
        out = _qp(c, geo, k, n, _pad(f_prev, H0, geo.E, len(c.link)), settings, records)
        if out[2] == _CONVERGED:
            return out
    # every frame's LP is feasible but the QP failed (a solver failure, not an infeasible motion): the LPs' witness
    lam, basis, status, _, args, _ = out
    _, _, zl = _frame_feasible(c, geo, k, n, settings, records)
    M = args["points"].shape[2]
    return zl.reshape(n, M, 4).clamp_min(0).numpy(), basis, status, float("nan"), args, None


def _pad(f_prev: np.ndarray, H_old: int, E: int, H_new: int | None = None) -> np.ndarray:
    """f_prev (H_old + E, 3) with zero rows for hand slots added after it (H_new - H_old of them)."""
    H_new = H_old if H_new is None else H_new
    return np.concatenate([f_prev[:H_old], np.zeros((H_new - H_old, 3)), f_prev[H_old:H_old + E]], 0)


# ------------------------------------------------------------------------------------------------ the whole motion
def plan_motion(scene, grasp: Grasp, settings: PlanSettings | None = None, *, hand=None) -> ForcePlan:
    """Plan contact forces for ``scene``'s object motion from ``grasp`` (module docstring; rigid grasp, planning
    stage only: the hand-motion synthesis of Liu's Sec. 5 is not part of this function).

    Args:
        scene: a :class:`~torchhand.scene.Scene` (object, its pose track, friction, table); its hand tracks are
            not used
        grasp: the grasp on the scene's object; snapped here (``settings.snap_tol``) when it has no contacts
        settings: :class:`PlanSettings`
        hand: the grasp's hand model (default :func:`~torchhand.manipulation.grasp.grasp_hand`)

    Returns:
        :class:`ForcePlan`

    Raises:
        GraspUnsuitable: a window stays infeasible whatever contacts are added (frame and wrench deficit);
        InputValueError / UnknownNameError: a grasp that does not fit its hand or cannot be snapped.
    """
    settings = settings or PlanSettings()
    t_start = time.perf_counter()
    run = _start(scene, grasp, settings, hand)
    t_stage1 = time.perf_counter()
    f_prev, z = run.f_init_vals, None
    for k in range(run.geo.T):
        t0 = time.perf_counter()
        f_prev, z = _step(run, k, f_prev, z)
        run.per_frame.append(time.perf_counter() - t0)
    return _assemble(run, t_start, t_stage1)


@dataclass
class _Run:
    """The working state of one planning run: geometry, contacts, kept problems, Stage 1's F_{-1} and the frames
    planned so far (mutable; :func:`plan_motion` and the manipulation loop step it frame by frame)."""

    geo: _Geometry
    c: _Contacts
    grasp: Grasp | tuple          # one grasp, or one per hand (snapped)
    settings: PlanSettings
    records: list | None
    f_init_h: int
    f_init_vals: np.ndarray
    out: list = field(default_factory=list)
    per_frame: list = field(default_factory=list)


def _start(scene, grasp, settings: PlanSettings, hand=None) -> _Run:
    """Snap the grasp(s) if needed, build the geometry and contacts, and solve Stage 1 (F_{-1}). ``grasp``: one
    :class:`Grasp` or a sequence of them (one per hand, different sides); ``hand``: its hand model, or a sequence
    matching the grasps (None: :func:`grasp_hand`)."""
    grasps = [grasp] if isinstance(grasp, Grasp) else list(grasp)
    hands = list(hand) if isinstance(hand, (list, tuple)) else [hand] * len(grasps)
    if not grasps or len(grasps) > 2 or len(hands) != len(grasps):
        raise InputValueError(f"grasp: expected one grasp or one per hand (two at most), got {len(grasps)} grasp(s) "
                              f"and {len(hands)} hand model(s)")
    if len({g.side for g in grasps}) != len(grasps):
        raise InputValueError(f"grasp: two grasps of the same side ({grasps[0].side}); one per hand")
    for j, g in enumerate(grasps):
        hands[j] = (hands[j] or grasp_hand(g)).to("cpu", torch.float64)
        check_grasp_hand(g, hands[j])
        if not g.has_contacts:
            grasps[j], _ = snap_grasp(g, hands[j], scene.object.mesh, tol=settings.snap_tol)
    geo = _Geometry(scene, grasps, hands, settings)
    if geo.T < 1:
        raise InputValueError("scene: the object motion has no frames")
    grasp = grasps[0] if len(grasps) == 1 else tuple(grasps)
    c = _initial_contacts(geo, grasps)
    records: list | None = [] if settings.keep_problems else None
    # Stage 1: F_{-1} = argmin sum |f|^2 s.t. Eq. 1 at frame 0 (f_prev = 0 makes Eq. 3 exactly that).
    lam, basis, status, _, _, _ = _solve(c, geo, 0, 1, np.zeros((len(c.link) + geo.E, 3)), settings, records)
    f_prev = np.einsum("mij,mj->mi", basis[0], lam[0])
    return _Run(geo=geo, c=c, grasp=grasp, settings=settings, records=records, f_init_h=len(c.link), f_init_vals=f_prev)


def _step(run: _Run, k: int, f_prev: np.ndarray, z=None):
    """Plan window k (Eq. 4, contacts added when infeasible) and keep F_k. f_prev: F_{k-1} per slot of the
    previous frame, (H_prev + E, 3). Returns (F_k (H + E, 3), the window solution for the next warm start)."""
    c, geo, E = run.c, run.geo, run.geo.E
    n = min(run.settings.window, geo.T - k)
    H_before = len(f_prev) - E
    lam, basis, status, obj, args, z = _solve(c, geo, k, n, _pad(f_prev, H_before, E, len(c.link)), run.settings,
                                              run.records, z)
    f_k = np.einsum("mij,mj->mi", basis[0], lam[0])
    run.out.append([len(c.link), lam[0], f_k, args["points"][0, 0].numpy(), args["normals"][0, 0].numpy(),
                    args["mask"][0, 0].numpy(), status, obj])
    return f_k, z


def _assemble(run: _Run, t_start: float, t_stage1: float) -> ForcePlan:
    c, geo, E, out = run.c, run.geo, run.geo.E, run.out
    f_init_h, f_init_vals, records, per_frame = run.f_init_h, run.f_init_vals, run.records, run.per_frame
    # Assemble (T, K) arrays: hand slots in order of creation, then table slots.
    H = len(c.link)
    K, T = H + E, geo.T
    forces, lams = np.zeros((T, K, 3)), np.zeros((T, K, 4))
    points, normals, mask = np.zeros((T, K, 3)), np.zeros((T, K, 3)), np.zeros((T, K), dtype=bool)
    status_t, obj_t = np.zeros(T, dtype=np.int8), np.zeros(T)
    for t, (h, lam_t, f_t, p_t, n_t, m_t, st, ob) in enumerate(out):
        sl = np.r_[np.arange(h), H + np.arange(E)]
        forces[t, sl], lams[t, sl], points[t, sl], normals[t, sl], mask[t, sl] = f_t, lam_t, p_t, n_t, m_t
        status_t[t], obj_t[t] = st, ob
    f_init = np.zeros((K, 3))
    f_init[np.r_[np.arange(f_init_h), H + np.arange(E)]] = f_init_vals
    added_at = np.array([s if src >= 0 else -1 for s, src in zip(c.start, c.source)] + [-1] * E, dtype=np.int64)
    added = mask & (added_at >= 0)[None]
    hand_flags = np.array([True] * H + [False] * E)
    links = tuple(geo.link_name(l) for l in c.link) + ("table",) * E
    t_end = time.perf_counter()
    return ForcePlan(
        forces=forces, lam=lams, points=points, normals=normals, mask=mask, hand=hand_flags, links=links,
        hand_local=np.concatenate([np.stack(c.h), np.zeros((E, 3))]) if H else np.zeros((K, 3)),
        object_local=np.concatenate([np.stack(c.p), np.zeros((E, 3))]) if H else np.zeros((K, 3)),
        added=added, added_at=added_at, added_from=np.array(c.source + [-1] * E, dtype=np.int64), f_init=f_init,
        com=geo.com, wrench=geo.wrench, status=status_t, objective=obj_t,
        timings={"stage1_s": t_stage1 - t_start, "plan_s": t_end - t_stage1, "per_frame_s": per_frame},
        records=tuple(records or ()))

