"""Settings, variants and results of resynthesis (:mod:`torchhand.interaction.resynth`).

:class:`Variant` (one rollout's mass, friction and compliance scale), :class:`ResynthSettings`, and the typed result:
:class:`Rollout` per variant (with its :class:`RolloutStatus`) in a :class:`ResynthResult`. Units: metres, seconds,
radians, newtons, kilograms; compliance rad/(N m) (root linear m/N).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import torch

from ..errors import InputValueError
from .grip import GripSettings
from .reach import ReachSettings

__all__ = ["Variant", "expand_variants", "ResynthSettings", "RolloutStatus", "Rollout", "ResynthResult"]


@dataclass(frozen=True)
class Variant:
    """One rollout's changes: mass (kg, None = the object's), friction (hand-object mu, None = the scene's),
    compliance_scale (multiplies the whole C) and object (a :class:`~torchhand.geometry.objects.RigidObject` in
    place of the scene's, at the scene's frame-0 pose; None = the scene's; the rollouts of one batch may each have
    their own, with exact-mesh contacts)."""

    mass: float | None = None
    friction: float | None = None
    compliance_scale: float = 1.0
    object: object = None

    def __post_init__(self):
        if self.mass is not None and not self.mass > 0:
            raise InputValueError(f"--mass: expected > 0 kg, got {self.mass}")
        if self.friction is not None and not self.friction >= 0:
            raise InputValueError(f"--friction: expected >= 0, got {self.friction}")
        if not self.compliance_scale > 0:
            raise InputValueError(f"--compliance-scale: expected > 0, got {self.compliance_scale}")

    def object_of(self, scene):
        """The rollout's object: its own, or the scene's."""
        return scene.object if self.object is None else self.object

    def as_dict(self) -> dict:
        return {"mass": self.mass, "friction": self.friction, "compliance_scale": self.compliance_scale,
                "object": None if self.object is None else self.object.name}


def expand_variants(masses=(None,), scales=(1.0,), frictions=(None,)) -> tuple:
    """All combinations (mass major, then compliance scale, then friction) as :class:`Variant` s."""
    return tuple(Variant(m, f, s) for m, s, f in itertools.product(masses, scales, frictions))


@dataclass(frozen=True)
class ResynthSettings:
    """Settings of :func:`~torchhand.interaction.resynth.resynthesize`.

    dt: step h, seconds (None: 1 / the scene's fps); pyramid_m: friction pyramid pairs (4); solver: "lemke" |
    "pgs" | "auto" | None (None: Lemke in float64, warm-started per rollout, so that every rollout of a batch is
    solved as it would be alone; "auto" - batched PGS, Lemke for stragglers - in float32, where Lemke cycles on the
    rounded problems of resting contacts);
    margin: contact candidate distance, metres; settle_steps: steps at the frame-0 reference before the first frame;
    close_open: before them, the paper's settle (the fingers' references moved from frame 0 to where every finger
    the interaction pushes with pushes and back, the root held; needs the interaction's ``theta``);
    support_points: most object-table slots; grip: :class:`~torchhand.interaction.grip.GripSettings`;
    hold_frame: frame the object slip is measured from (None: the first frame at which the reference root has moved
    more than 1 mm from its start); dtype: torch dtype of the rollouts; pgs_max_iters: PGS sweeps before a
    rollout's LCP goes to Lemke ("auto") or fails ("pgs"): 200, because the object's rigid-body coupling between
    contacts makes PGS converge slowly, and Lemke is cheaper for what PGS has not solved by then; object_contacts:
    "mesh" (default: each link's capsule against the object's exact mesh, trimesh's closest points, the geometry
    ``torchhand check`` measures; see :mod:`._contacts`) or "sdf" (the deepest surface sample of each link in a signed
    distance grid of ``sdf_voxel`` metres, 1 mm by default, with the grid's trilinear normals: about 20 % cheaper per
    step on the demo's box, but blended normals within a voxel of an edge); self_contacts: finger-finger contact slots
    in the step (:mod:`._contacts`), so that a finger closing further on a smaller object stops on its neighbour
    instead of passing through it; finger_friction: friction coefficient of those slots (0: frictionless);
    lemke_warm: Lemke starts from the previous step's support
    (:class:`~torchhand.interaction.step.StepSettings`); reach: :class:`~torchhand.interaction.reach.ReachSettings`
    (a finger the reference pushes with that does not touch closes on; off by default); device: "cpu" or "cuda"
    (or "cuda:N"), where the step's tensors live (the exact-mesh queries and the per-rollout LCPs run on the CPU
    either way)
    """

    dt: float | None = None
    pyramid_m: int = 4
    solver: str | None = None
    margin: float = 0.005
    settle_steps: int = 0
    close_open: bool = False
    support_points: int = 16
    grip: GripSettings = GripSettings()
    hold_frame: int | None = None
    dtype: torch.dtype = torch.float64
    pgs_max_iters: int | None = 200
    object_contacts: str = "mesh"
    sdf_voxel: float = 0.001
    self_contacts: bool = True
    lemke_warm: bool = True
    finger_friction: float = 0.0
    device: str = "cpu"
    reach: ReachSettings = ReachSettings()

    def __post_init__(self):
        if self.dt is not None and not self.dt > 0:
            raise InputValueError(f"--dt: expected > 0 seconds, got {self.dt}")
        if not (isinstance(self.pyramid_m, int) and self.pyramid_m >= 1):
            raise InputValueError(f"--pyramid-m: expected an integer >= 1, got {self.pyramid_m!r}")
        if self.solver not in (None, "lemke", "pgs", "auto"):
            raise InputValueError(f"--solver: expected lemke, pgs or auto, got {self.solver!r}")
        if not self.settle_steps >= 0:
            raise InputValueError(f"--settle-steps: expected >= 0, got {self.settle_steps}")
        if self.object_contacts not in ("mesh", "sdf"):
            raise InputValueError(f"object_contacts: expected 'mesh' or 'sdf', got {self.object_contacts!r}")
        if not (isinstance(self.finger_friction, (int, float)) and self.finger_friction >= 0):
            raise InputValueError(f"--finger-friction: expected a coefficient >= 0, got {self.finger_friction!r}")
        if not (isinstance(self.device, str) and (self.device == "cpu" or self.device.split(":")[0] == "cuda")):
            raise InputValueError(f"--device: expected cpu or cuda, got {self.device!r}")
        if not self.sdf_voxel > 0:
            raise InputValueError(f"sdf_voxel: expected > 0 metres, got {self.sdf_voxel}")


class RolloutStatus(IntEnum):
    """How a rollout ended."""

    COMPLETED = 0
    LCP_FAILED = 1

    @property
    def message(self) -> str:
        return {0: "every step solved",
                1: "the contact LCP was not solved at a step; the rollout stopped there (try --solver lemke, a "
                   "smaller --dt, or --pyramid-m 4)"}[int(self)]


@dataclass(frozen=True, eq=False)
class Rollout:
    """One rollout, NumPy float64 (T frames, D joints, Nh hand-object slots, P object-table slots).

    variant: :class:`Variant`; status: :class:`RolloutStatus`; failed_step: step whose LCP failed, or -1;
    failed_status: the solver status name at that step, or ""
    q: (T, D) rad; root_pose: (T, 4, 4); object_pose: (T, 4, 4); theta_r: (T, D) rad; compliance: (T, 6 + D)
    slot_link: link of each hand-object slot, (Nh,); contact_mask: slot holds a force, (T, Nh); contact_point:
    on the object surface, (T, Nh, 3) m; contact_normal: into the object, (T, Nh, 3); contact_force: hand on
    object, (T, Nh, 3) N; contact_sliding: lambda_i > 0, (T, Nh); slip_ratio: rho_i, (T, Nh)
    env_mask, env_point, env_force: object-table slots, (T, P), (T, P, 3) m, (T, P, 3) N (table on object)
    lcp_status: (T,) int8; lcp_residual: (T,); theta_err: ||theta_err||_inf, (T,); joint_clamp: how far the step into
    frame k clamped a finger joint back into the hand's limits, (T,) rad (0 at frame 0); grip_events: (G, 2) int64 rows
    (frame, link); grip_onset: first slip frame or -1; object_slip: object centre displacement in the hand frame since
    ``hold_frame``, (T,) m; hold_frame: int
    """

    variant: Variant
    status: RolloutStatus
    failed_step: int
    failed_status: str
    q: np.ndarray
    root_pose: np.ndarray
    object_pose: np.ndarray
    theta_r: np.ndarray
    compliance: np.ndarray
    slot_link: np.ndarray
    contact_mask: np.ndarray
    contact_point: np.ndarray
    contact_normal: np.ndarray
    contact_force: np.ndarray
    contact_sliding: np.ndarray
    slip_ratio: np.ndarray
    env_mask: np.ndarray
    env_point: np.ndarray
    env_force: np.ndarray
    lcp_status: np.ndarray
    lcp_residual: np.ndarray
    theta_err: np.ndarray
    joint_clamp: np.ndarray
    grip_events: np.ndarray
    grip_onset: int
    object_slip: np.ndarray
    hold_frame: int

    @property
    def ok(self) -> bool:
        return self.status == RolloutStatus.COMPLETED


@dataclass(frozen=True, eq=False)
class ResynthResult:
    """rollouts: one :class:`Rollout` per variant; scene: the output scene (T frames at 1/h fps, the first
    completed rollout's object and wrist motion and mass); hand: HandModel; fps: 1/h; timings: seconds;
    settings: :class:`ResynthSettings`; source: the interaction's source; scenes: each rollout's output scene"""

    rollouts: tuple
    scene: object
    hand: object
    fps: float
    timings: dict
    settings: ResynthSettings
    source: str = ""
    scenes: tuple = ()

    def variant_result(self, i: int) -> "ResynthResult":
        """Rollout ``i`` alone, with its own output scene (its object, mass and motion): the result of one variant,
        for a result directory of its own (a batch with several objects writes one per variant)."""
        scene = self.scenes[i] if self.scenes else self.scene
        return dataclasses.replace(self, rollouts=(self.rollouts[i],), scene=scene, scenes=(scene,))
