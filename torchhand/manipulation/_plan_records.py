"""The records of contact-force planning (:mod:`.plan`): its settings, the :class:`ForcePlan` it returns, the
problems it keeps (:class:`WindowRecord`) and :class:`GraspUnsuitable`, raised when no set of added contacts makes
a window feasible."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputValueError
from ..kernels.force_plan import FrameLPs, WindowQP
from .snap import SNAP_TOL


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
    qp_solver: "dense" (one problem at a time in NumPy / LAPACK, :func:`torchhand.solvers.qp.solve` with ``backend="dense"``; the
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
