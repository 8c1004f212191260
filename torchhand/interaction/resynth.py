"""Resynthesis of an interaction trajectory on a new object or environment (Kry & Pai 2006 §7-8), B rollouts at once.

Pipeline (pure stages over frozen state)::

    inter = load_interaction("interaction.npz")           # C(t), theta_r(t), root reference
    result = resynthesize(inter, scene, variants=expand_variants([0.2, 0.5], [1.0, 0.5]),
                          settings=ResynthSettings(grip=GripSettings("delayed")))
    write_resynthesis(result, "out/")                     # the result directory of docs/result_format.md

1. References at the simulation times t_k = k h (h = 1/fps of the scene, or ``settings.dt``), k = 0 .. T - 1 over
   the interaction's duration: theta_r and the six root coordinates interpolated linearly, C(t) held from the latest
   frame (piecewise constant, as estimated). The root reference is the root pose ``root_origin`` displaced by the
   interaction's ``root_theta_r`` (rotation vector applied on the left, translation added; ``root_origin`` is the
   interaction's own when it holds one, else the scene's wrist pose at frame 0).
2. Variants: each rollout b has its object mass (inertia scaled with it), its hand-object friction and a scale of the
   whole compliance C; they share one batched step (:func:`~torchhand.interaction.step.quasi_static_step`).
3. Set-up (design note Stage 8, §3 item 11): the object starts at the scene's frame-0 pose on the table; the hand
   starts at the reference's frame 0. Deviation: the paper pushes the object to an improved start by simulating the
   grasping motion until every finger touches and back; here ``settle_steps`` steps at the frame-0 reference let
   the object come to rest on the table first, and the closing motion is expected in the interaction itself (the
   captured approach and closing, or a constructed one).
4. Steps k -> k + 1 (§7.1): contacts of the hand with the object (each link's capsule against the exact mesh, the
   geometry ``torchhand check`` measures; ``object_contacts="sdf"`` for a grid instead) and the table, of the object
   with the table (object-plane slots, an extension: see :mod:`.step`) and between fingers (finger-finger slots, an
   extension, ``self_contacts``); joint limits clamp theta^{k+1} (reported per frame); the LCP by Lemke's method (one
   rollout) or the batched projected Gauss-Seidel with Lemke for stragglers (several); object integration; contact
   update.
5. Grip adjustment (§8.1, :mod:`.grip`): the compliance of each rollout is scaled down on slip.
6. A rollout whose LCP is not solved at step k stops there (its status names the step); the others go on.

Frame k of a rollout holds the state at t_k (q, root, object pose, contact points and normals) and the contact
forces f^{k+1} solved at step k, which act on the object between t_k and t_{k+1} (the explicit-in-position,
implicit-in-force discretisation of §7.1.2), so that the second difference of the object's positions around frame
k matches the forces stored at frame k. The written contact point of a hand contact is on the object surface
(the hand point moved back along the normal by its separation).

Units: metres, seconds, radians, newtons, kilograms; compliance rad/(N m) (root linear m/N).
"""

from __future__ import annotations

import dataclasses
import itertools
import sys
import time
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

import numpy as np
import torch

from .._npz import read_npz
from .._numerics import record as numerics_record
from ..errors import FileFormatError, InputValueError, UnknownNameError
from ..kernels.status import SolverStatus
from ._contacts import BODY_OBJECT, BODY_OBJECT_ENV, TablePlane, support_points
from .grip import GripSettings, grip_update, init_grip, path_mask
from .step import StepObject, StepSettings, displace_root, initial_state, quasi_static_step

__all__ = ["Interaction", "load_interaction", "save_interaction", "Variant", "expand_variants", "ResynthSettings",
           "RolloutStatus", "Rollout", "ResynthResult", "simulate", "resynthesize", "object_slip",
           "solution_arrays", "write_resynthesis", "prepare_result_dir"]

_CONVERGED = int(SolverStatus.CONVERGED)


# ---------------------------------------------------------------------------------------------------------------
# input: the interaction trajectory


@dataclass(frozen=True, eq=False)
class Interaction:
    """An interaction trajectory (C, theta_r) of T frames, NumPy float64.

    fps: frames per second; joint_names: (D,) str; C: compliance of the 6 + D coordinates, (T, 6 + D), rad/(N m)
    (root linear m/N); theta_r: reference joints, (T, D), radians; root_theta_r: reference root coordinates,
    (T, 6): rotation vector (rad) and translation (m) relative to ``root_origin``; root_origin: (4, 4) world pose
    the root coordinates are relative to, or None (the scene's first wrist pose); source: "measured" | "synthetic" |
    "inferred" | "constructed" | ""
    """

    fps: float
    joint_names: tuple
    C: np.ndarray
    theta_r: np.ndarray
    root_theta_r: np.ndarray
    root_origin: np.ndarray | None = None
    source: str = ""

    @property
    def T(self) -> int:
        return int(self.theta_r.shape[0])

    @property
    def duration(self) -> float:
        return (self.T - 1) / self.fps


def _key(data, name: str, path, shape=None) -> np.ndarray:
    if name not in data:
        raise FileFormatError(f"{path}: missing key '{name}'")
    x = np.asarray(data[name])
    if shape is not None and (x.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, x.shape))):
        want = "(" + ", ".join("?" if s is None else str(s) for s in shape) + ")"
        raise FileFormatError(f"{path}: '{name}' has shape {x.shape}, expected {want}")
    return x


def load_interaction(path) -> Interaction:
    """Read ``interaction.npz`` (docs/interaction_capture.md): ``C``, ``theta_r``, ``root_theta_r``, ``fps``,
    ``joint_names``; optional ``root_origin`` (4, 4) and ``source``.

    raises: MissingFileError, FileFormatError (missing key, wrong shape or dtype, T mismatch), InputValueError
        (NaN or inf with the first bad frame, fps <= 0, compliance < 0)
    """
    path = Path(path)
    data = read_npz(path, ("C", "theta_r", "root_theta_r", "fps", "joint_names"),
                    "an interaction (docs/interaction_capture.md)")
    theta_r = _key(data, "theta_r", path, (None, None)).astype(np.float64)
    T, D = theta_r.shape
    C = _key(data, "C", path, (T, 6 + D)).astype(np.float64)
    root = _key(data, "root_theta_r", path, (T, 6)).astype(np.float64)
    fps = float(_key(data, "fps", path, ()))
    names = tuple(str(n) for n in _key(data, "joint_names", path, (D,)))
    origin = _key(data, "root_origin", path, (4, 4)).astype(np.float64) if "root_origin" in data else None
    if not fps > 0:
        raise InputValueError(f"{path}: fps must be > 0, got {fps}")
    for name, x in (("theta_r", theta_r), ("C", C), ("root_theta_r", root)):
        bad = ~np.isfinite(x).reshape(T, -1).all(1)
        if bad.any():
            raise InputValueError(f"{path}: '{name}' is not finite at frame {int(np.argmax(bad))}")
    if (C < 0).any():
        raise InputValueError(f"{path}: 'C' has negative compliance at frame {int(np.argmax((C < 0).any(1)))}")
    if T < 2:
        raise InputValueError(f"{path}: needs at least 2 frames, got {T}")
    source = str(data["source"]) if "source" in data else ""
    return Interaction(fps, names, C, theta_r, root, origin, source)


def save_interaction(inter: Interaction, path) -> Path:
    """Write an :class:`Interaction` as ``interaction.npz`` (atomically; the keys :func:`load_interaction` reads)."""
    import io

    from .._atomic import atomic_bytes

    data = {"C": inter.C, "theta_r": inter.theta_r, "root_theta_r": inter.root_theta_r, "fps": np.array(inter.fps),
                "joint_names": np.array(inter.joint_names), "source": np.array(inter.source),
                "names": np.array(("root_rx", "root_ry", "root_rz", "root_x", "root_y", "root_z") + inter.joint_names)}
    if inter.root_origin is not None:
        data["root_origin"] = inter.root_origin
    buf = io.BytesIO()
    np.savez_compressed(buf, **data)
    atomic_bytes(Path(path), buf.getvalue())
    return Path(path)


# ---------------------------------------------------------------------------------------------------------------
# settings, variants, records


@dataclass(frozen=True)
class Variant:
    """One rollout's changes: mass (kg, None = the scene's), friction (hand-object mu, None = the scene's) and
    compliance_scale (multiplies the whole C)."""

    mass: float | None = None
    friction: float | None = None
    compliance_scale: float = 1.0

    def __post_init__(self):
        if self.mass is not None and not self.mass > 0:
            raise InputValueError(f"--mass: expected > 0 kg, got {self.mass}")
        if self.friction is not None and not self.friction >= 0:
            raise InputValueError(f"--friction: expected >= 0, got {self.friction}")
        if not self.compliance_scale > 0:
            raise InputValueError(f"--compliance-scale: expected > 0, got {self.compliance_scale}")

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def expand_variants(masses=(None,), scales=(1.0,), frictions=(None,)) -> tuple:
    """All combinations (mass major, then compliance scale, then friction) as :class:`Variant` s."""
    return tuple(Variant(m, f, s) for m, s, f in itertools.product(masses, scales, frictions))


@dataclass(frozen=True)
class ResynthSettings:
    """Settings of :func:`resynthesize`.

    dt: step h, seconds (None: 1 / the scene's fps); pyramid_m: friction pyramid pairs (4); solver: "lemke" |
    "pgs" | "auto" | None (None: Lemke for one float64 rollout, "auto" - batched PGS, Lemke for stragglers - for
    several or in float32, where Lemke cycles on the rounded problems of resting contacts);
    margin: contact candidate distance, metres; settle_steps: steps at the frame-0 reference before the first frame;
    support_points: most object-table slots; grip: :class:`~torchhand.interaction.grip.GripSettings`;
    hold_frame: frame the object slip is measured from (None: the first frame at which the reference root has moved
    more than 1 mm from its start); dtype: torch dtype of the rollouts; pgs_max_iters: PGS sweeps before a
    rollout's LCP goes to Lemke ("auto") or fails ("pgs"): 200, because the object's rigid-body coupling between
    contacts makes PGS converge slowly, and Lemke is cheaper for what PGS has not solved by then; object_contacts:
    "mesh" (default: each link's capsule against the object's exact mesh, trimesh's closest points, the geometry
    ``torchhand check`` measures; see :mod:`._contacts`) or "sdf" (the deepest surface sample of each link in a signed
    distance grid of ``sdf_voxel`` metres, 1 mm by default, with the grid's trilinear normals: about 20 % cheaper per
    step on the demo's box, but blended normals within a voxel of an edge); self_contacts: finger-finger contact slots
    in the step (frictionless; :mod:`._contacts`), so that a finger closing further on a smaller object stops on its
    neighbour instead of passing through it
    """

    dt: float | None = None
    pyramid_m: int = 4
    solver: str | None = None
    margin: float = 0.005
    settle_steps: int = 0
    support_points: int = 16
    grip: GripSettings = GripSettings()
    hold_frame: int | None = None
    dtype: torch.dtype = torch.float64
    pgs_max_iters: int | None = 200
    object_contacts: str = "mesh"
    sdf_voxel: float = 0.001
    self_contacts: bool = True

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
    settings: :class:`ResynthSettings`; source: the interaction's source"""

    rollouts: tuple
    scene: object
    hand: object
    fps: float
    timings: dict
    settings: ResynthSettings
    source: str = ""


# ---------------------------------------------------------------------------------------------------------------
# the rollout loop


def object_slip(root_pose: np.ndarray, object_pose: np.ndarray, com: np.ndarray, start: int) -> np.ndarray:
    """Displacement of the object's centre in the hand (root) frame since frame ``start``, (T,), metres."""
    c = object_pose[:, :3, :3] @ com + object_pose[:, :3, 3]
    R, p = root_pose[:, :3, :3], root_pose[:, :3, 3]
    local = np.einsum("tji,tj->ti", R, c - p)
    return np.linalg.norm(local - local[min(max(start, 0), len(local) - 1)], axis=-1)


def _hold_frame(root_r: np.ndarray, given: int | None) -> int:
    if given is not None:
        return int(given)
    moved = np.linalg.norm(root_r[:, :3, 3] - root_r[0, :3, 3], axis=-1) > 1e-3
    return int(np.argmax(moved)) if moved.any() else 0


def simulate(hand, obj: StepObject, env: TablePlane | None, theta_r: torch.Tensor, root_r: torch.Tensor,
             C: torch.Tensor, object_pose0: torch.Tensor, *, settings: StepSettings,
             grip: GripSettings = GripSettings(), settle_steps: int = 0, progress=None) -> dict:
    """Run B rollouts over T frames (module docstring, stages 4-6).

    hand: HandModel (the rollouts' dtype); obj: :class:`StepObject` (per-rollout ``masses``/``mus`` allowed);
    env: the table or None; theta_r: (B, T, D) rad; root_r: (B, T, 4, 4); C: (B, T, 6 + D) (variant scales applied);
    object_pose0: (B, 4, 4); settings: :class:`StepSettings`; grip: :class:`GripSettings`; progress: callable(str)
    returns: dict of per-frame tensors (CPU) and per-rollout ``failed_step`` (B,) (-1: completed),
        ``failed_status`` (B,) int8, ``grip_events`` list of (rollout, frame, link), ``onset`` (B,)
    """
    B, T, D = theta_r.shape
    like = theta_r
    state = initial_state(hand, theta_r[:, 0], root_r[:, 0], object_pose=object_pose0, obj=obj, env=env,
                          settings=settings)
    c = state.contacts
    hand_obj = (c.body == BODY_OBJECT).cpu()
    if bool(((state.contacts.separation < -0.005) & state.contacts.mask & (c.body == BODY_OBJECT)).any()):
        raise InputValueError("the object starts more than 5 mm inside the hand at frame 0; move the object or start "
                              "the interaction from an open hand")
    for _ in range(settle_steps):
        state, _ = quasi_static_step(state, hand, theta_r[:, 0], root_r[:, 0], C[:, 0], obj, env, settings)
    paths = path_mask(hand, c.link)
    gs = init_grip(B, 6 + D, c.mask.shape[1], settings.h, grip, like)
    alive = torch.ones(B, dtype=torch.bool)
    failed_step = torch.full((B,), -1, dtype=torch.long)
    failed_status = torch.zeros(B, dtype=torch.int8)
    rec = {k: [] for k in ("q", "root", "object_pose", "C", "points", "d0", "sep", "body_mask", "forces", "lam",
                           "mu", "status", "residual", "theta_err", "joint_clamp")}
    events = []
    t0 = time.perf_counter()
    for k in range(T):
        Ck = C[:, k] * gs.scale
        nxt = min(k + 1, T - 1)
        new, rep = quasi_static_step(state, hand, theta_r[:, nxt], root_r[:, nxt], Ck, obj, env, settings)
        sc = state.contacts
        f = torch.einsum("bnrk,bnk->bnr", rep.D, rep.beta)
        mu = rep.lcp.mu.new_zeros(B, sc.mask.shape[1]).scatter(1, rep.order, rep.lcp.mu)
        for name, x in (("q", state.q), ("root", state.root), ("object_pose", state.object_pose), ("C", Ck),
                        ("points", sc.points), ("d0", sc.d0), ("sep", sc.separation), ("body_mask", sc.mask),
                        ("forces", f), ("lam", rep.lam), ("mu", mu), ("status", rep.status),
                        ("residual", rep.residual), ("theta_err", state.theta_err.abs().amax(-1)),
                        ("joint_clamp", rep.joint_clamp)):
            rec[name].append(x.detach().cpu())
        bad = alive & (rep.status.cpu() != _CONVERGED)
        if bool(bad.any()):
            failed_step[bad] = k
            failed_status[bad] = rep.status.cpu()[bad]
            alive &= ~bad
        gs, ev = grip_update(gs, k, f, rep.lam, sc, mu, paths, grip)
        events += [e for e in ev if bool(alive[e[0]])]
        state = new
        if progress is not None and (k + 1) % 50 == 0:
            el = time.perf_counter() - t0
            progress(f"step {k + 1}/{T}: {1e3 * el / (k + 1):.1f} ms/step, {int(alive.sum())}/{B} rollouts running")
    out = {k: torch.stack(v, 1) for k, v in rec.items()}
    out.update(failed_step=failed_step, failed_status=failed_status, grip_events=events, onset=gs.onset.cpu(),
               slot_link=c.link.cpu(), slot_body=c.body.cpu(), hand_obj=hand_obj,
               step_time_s=(time.perf_counter() - t0) / max(T, 1))
    return out


def _rollout(rec: dict, b: int, variant: Variant, theta_r: np.ndarray, com: np.ndarray, hold: int) -> Rollout:
    f64 = lambda x: x[b].double().numpy()
    body = rec["slot_body"].numpy()
    hs, es = np.nonzero(body == BODY_OBJECT)[0], np.nonzero(body == BODY_OBJECT_ENV)[0]
    d0, pts, sep, force = f64(rec["d0"]), f64(rec["points"]), f64(rec["sep"]), f64(rec["forces"])
    active = rec["body_mask"][b].numpy()
    fn = (force * d0).sum(-1)
    # hand-object: force on the object = -f (f is on the hand); normal into the object = -d0
    # a slot is written as a contact when it pushes (f_n > 1 nN: the LCP's zero forces come out at round-off level)
    hmask = active[:, hs] & (fn[:, hs] > 1e-9)
    m3 = hmask[..., None]
    point = (pts[:, hs] - sep[:, hs, None] * d0[:, hs]) * m3
    fh = -force[:, hs] * m3
    ft = np.linalg.norm(force[:, hs] - fn[:, hs, None] * d0[:, hs], axis=-1)
    rho = np.where(hmask & (fn[:, hs] > 0.2), ft / np.maximum(fn[:, hs], 1e-12), 0.0)
    lam = f64(rec["lam"])[:, hs]
    emask = active[:, es] & (fn[:, es] > 0)
    failed = int(rec["failed_step"][b])
    ev = np.array([(k, l) for bb, k, l in rec["grip_events"] if bb == b], dtype=np.int64).reshape(-1, 2)
    root, obj = f64(rec["root"]), f64(rec["object_pose"])
    clamp = np.concatenate([[0.0], f64(rec["joint_clamp"])[:-1]])        # step k clamps the joints of frame k + 1
    return Rollout(
        variant=variant, status=RolloutStatus.COMPLETED if failed < 0 else RolloutStatus.LCP_FAILED,
        failed_step=failed, failed_status="" if failed < 0 else SolverStatus(int(rec["failed_status"][b])).name,
        q=f64(rec["q"]), root_pose=root, object_pose=obj, theta_r=theta_r, compliance=f64(rec["C"]),
        slot_link=rec["slot_link"].numpy()[hs], contact_mask=hmask, contact_point=point,
        contact_normal=-d0[:, hs] * m3, contact_force=fh, contact_sliding=hmask & (lam > 1e-9), slip_ratio=rho,
        env_mask=emask, env_point=pts[:, es] * emask[..., None], env_force=force[:, es] * emask[..., None],
        lcp_status=rec["status"][b].numpy().astype(np.int8), lcp_residual=f64(rec["residual"]),
        theta_err=f64(rec["theta_err"]), joint_clamp=clamp, grip_events=ev, grip_onset=int(rec["onset"][b]),
        object_slip=object_slip(root, obj, com, hold), hold_frame=hold)


# ---------------------------------------------------------------------------------------------------------------
# a scene and an interaction


def _resample(inter: Interaction, h: float):
    """Reference at t_k = k h over the interaction's duration: theta_r, root coordinates (linear), C (held)."""
    T = int(np.floor(inter.duration / h + 1e-9)) + 1
    t = np.arange(T) * h * inter.fps
    i0 = np.clip(np.floor(t + 1e-9).astype(int), 0, inter.T - 1)
    i1 = np.minimum(i0 + 1, inter.T - 1)
    w = (t - i0)[:, None]
    lerp = lambda x: (1 - w) * x[i0] + w * x[i1]
    return lerp(inter.theta_r), lerp(inter.root_theta_r), inter.C[i0]


def _check_names(inter: Interaction, hand) -> None:
    if tuple(inter.joint_names) != tuple(hand.joint_names):
        missing = [n for n in inter.joint_names if n not in hand.joint_names]
        if missing:
            raise UnknownNameError(f"interaction joint '{missing[0]}' is not a joint of the scene's hand "
                                   f"({len(hand.joint_names)} joints: {', '.join(hand.joint_names[:4])}, ...)")
        raise InputValueError(f"interaction joint_names: the scene's hand has {len(hand.joint_names)} joints in "
                              f"another order; expected {hand.joint_names[:4]}..., got {inter.joint_names[:4]}...")


def resynthesize(inter: Interaction, scene, *, variants=(Variant(),), settings: ResynthSettings = ResynthSettings(),
                 progress=None) -> ResynthResult:
    """Resynthesise ``inter`` with the scene's object, table and hand, one rollout per variant (module docstring).

    inter: :class:`Interaction`; scene: :class:`~torchhand.scene.Scene` (one hand; its object's frame-0 pose is the
    start, its table and frictions the environment); variants: :class:`Variant` s (B >= 1); settings:
    :class:`ResynthSettings`; progress: callable(str) for progress lines, or None
    returns: :class:`ResynthResult`
    raises: InputValueError / UnknownNameError for inputs that do not fit (joint names, dt, ...)
    """
    from ..hand.mount import track_hand
    from ..geometry.sdf import SDFGrid

    t_start = time.perf_counter()
    if len(scene.hands) != 1:
        raise InputValueError(f"--scene: resynthesis drives one hand, the scene has {len(scene.hands)}")
    variants = tuple(variants)
    if not variants:
        raise InputValueError("variants: at least one rollout is needed")
    B = len(variants)
    h = settings.dt if settings.dt is not None else 1.0 / scene.fps
    if h > 1.0 / inter.fps + 1e-12:
        raise InputValueError(f"--dt: {h:g} s is longer than the interaction's frame time {1 / inter.fps:g} s")
    dtype = settings.dtype
    hand = track_hand(scene.hands[0]).to("cpu", dtype)
    _check_names(inter, hand)
    theta_r, root_c, C = _resample(inter, h)
    T = theta_r.shape[0]
    origin = inter.root_origin if inter.root_origin is not None else scene.hands[0].wrist_pose[0].double().numpy()
    root_r = displace_root(torch.from_numpy(origin).to(dtype).expand(T, 4, 4), torch.from_numpy(root_c).to(dtype))
    rigid = scene.object
    if settings.object_contacts == "mesh":
        sdf, mesh = None, True
    else:
        sdf, mesh = SDFGrid.from_mesh(rigid.mesh, settings.sdf_voxel, progress=False).to("cpu", dtype), None
    env = None
    if scene.environment.table:
        env = TablePlane((0.0, 0.0, 1.0), scene.environment.table_height, scene.environment.friction)
    sup = support_points(rigid.mesh.vertices, settings.support_points).to(dtype) if env is not None else None
    masses = tuple(rigid.mass if v.mass is None else v.mass for v in variants)
    mus = tuple(scene.friction if v.friction is None else v.friction for v in variants)
    obj = StepObject.from_rigid(rigid, sdf, scene.friction, support=sup, masses=masses, mus=mus, mesh=mesh)
    solver = settings.solver or ("lemke" if B == 1 and dtype == torch.float64 else "auto")
    step = StepSettings(h=h, pyramid_m=settings.pyramid_m, margin=settings.margin, solver=solver,
                        gravity=tuple(float(x) for x in scene.gravity), geometry="capsules",
                        pgs_max_iters=settings.pgs_max_iters, self_contacts=settings.self_contacts)
    scale = torch.tensor([v.compliance_scale for v in variants], dtype=dtype)
    Ct = torch.from_numpy(C).to(dtype)[None] * scale[:, None, None]
    th = torch.from_numpy(theta_r).to(dtype).expand(B, T, -1).contiguous()
    E0 = scene.object_pose[0].to(dtype).expand(B, 4, 4).contiguous()
    if progress is not None:
        progress(f"resynthesis: {B} rollout(s), {T} steps of {1e3 * h:.2f} ms, solver {solver}")
    t_sim = time.perf_counter()
    rec = simulate(hand, obj, env, th, root_r.expand(B, T, 4, 4).contiguous(), Ct, E0, settings=step,
                   grip=settings.grip, settle_steps=settings.settle_steps, progress=progress)
    t_sim = time.perf_counter() - t_sim
    hold = _hold_frame(root_r.double().numpy(), settings.hold_frame)
    com = np.asarray(rigid.com, dtype=np.float64)
    rollouts = tuple(_rollout(rec, b, variants[b], theta_r, com, hold) for b in range(B))
    first = next((r for r in rollouts if r.ok), rollouts[0])
    out_scene = _output_scene(scene, first, 1.0 / h)
    timings = {"simulate_s": t_sim, "per_step_ms": 1e3 * rec["step_time_s"],
               "total_s": time.perf_counter() - t_start}
    return ResynthResult(rollouts, out_scene, hand, 1.0 / h, timings, settings, inter.source)


def _output_scene(scene, rollout: Rollout, fps: float):
    """The scene of the result directory: the rollout's object and wrist motion, its mass, fps 1/h."""
    from ..scene import HandTrack

    obj = scene.object
    m = rollout.variant.mass
    if m is not None and m != obj.mass:
        obj = dataclasses.replace(obj, mass=float(m), inertia=np.asarray(obj.inertia) * (m / obj.mass))
    track = scene.hands[0]
    hands = (HandTrack(side=track.side, wrist_pose=torch.from_numpy(rollout.root_pose), length=track.length,
                       model=track.model),)
    return dataclasses.replace(scene, object=obj, object_pose=torch.from_numpy(rollout.object_pose), fps=float(fps),
                               hands=hands, source=None, external_wrench=None,
                               description=(scene.description + " Resynthesised interaction (Kry & Pai 2006).")
                               .strip())


# ---------------------------------------------------------------------------------------------------------------
# the result directory (docs/result_format.md)


def solution_arrays(result: ResynthResult, index: int) -> dict:
    """The npz arrays of rollout ``index``: the contract's keys (docs/result_format.md) and the extra keys
    ``theta_r``, ``compliance``, ``slip_ratio``, ``lcp_status``, ``lcp_residual``, ``theta_err``, ``joint_clamp``,
    ``grip_events``,
    ``object_slip``, ``variant_mass``, ``variant_friction``, ``variant_compliance_scale``."""
    from ..io.result import FORMAT_VERSION

    r = result.rollouts[index]
    hand = result.hand
    T = r.q.shape[0]
    counts = r.contact_mask.sum(1)
    K = int(counts.max()) if T else 0
    order = np.argsort(~r.contact_mask, axis=1, kind="stable")[:, :K]               # contacts first
    take = lambda x: np.take_along_axis(x, order[..., None] if x.ndim == 3 else order, axis=1)
    mask = take(r.contact_mask)
    link = np.where(mask, np.broadcast_to(r.slot_link, r.contact_mask.shape)[np.arange(T)[:, None], order], -1)
    mu = r.variant.friction if r.variant.friction is not None else result.scene.friction
    return {
        "format_version": np.array(FORMAT_VERSION), "q": r.q, "joint_names": np.array(hand.joint_names),
        "root_pose": r.root_pose, "object_pose": r.object_pose, "fps": np.array(float(result.fps)),
        "contact_mask": mask, "contact_link": link.astype(np.int64), "contact_link_name": np.array(hand.link_names),
        "contact_point": take(r.contact_point), "contact_normal": take(r.contact_normal),
        "contact_force": take(r.contact_force), "contact_sliding": take(r.contact_sliding) & mask,
        "env_contact_mask": r.env_mask, "env_contact_point": r.env_point, "env_contact_force": r.env_force,
        "strategy": np.array("kry_pai"), "friction": np.array(float(mu)), "reconstructed": np.array(False),
        "theta_r": r.theta_r, "compliance": r.compliance, "slip_ratio": take(r.slip_ratio) * mask,
        "lcp_status": r.lcp_status, "lcp_residual": r.lcp_residual, "theta_err": r.theta_err,
        "joint_clamp": r.joint_clamp,
        "grip_events": r.grip_events, "object_slip": r.object_slip,
        "variant_mass": np.array(float(r.variant.mass if r.variant.mass is not None else result.scene.object.mass)),
        "variant_friction": np.array(float(mu)),
        "variant_compliance_scale": np.array(float(r.variant.compliance_scale)),
    }


def _stats(result: ResynthResult, written: list) -> dict:
    from ..io.result import FORMAT_VERSION

    s = result.settings
    rolls = []
    for i, r in enumerate(result.rollouts):
        rolls.append({"variant": r.variant.as_dict(), "status": r.status.name, "message": r.status.message,
                      "failed_step": r.failed_step, "failed_status": r.failed_status,
                      "solution": written.index(i) if i in written else None,
                      "max_object_slip_m": float(r.object_slip.max()) if r.ok else None,
                      "grip_events": int(r.grip_events.shape[0]), "grip_onset_frame": r.grip_onset,
                      "max_theta_err": float(r.theta_err.max()), "max_lcp_residual": float(r.lcp_residual.max()),
                      "max_joint_clamp_rad": float(r.joint_clamp.max()),
                      "joint_clamp_frames": int((r.joint_clamp > 1e-9).sum())})
    return {"format_version": FORMAT_VERSION, "complete": True, "method": "kry_pai", "scene": result.scene.name,
            "T": result.scene.T, "fps": result.fps, "solutions": len(written), "rollouts": rolls,
            "time_s": result.timings.get("total_s"), "timings_s": result.timings,
            "per_step_ms": result.timings.get("per_step_ms"), "source": result.source,
            "settings": {"dt": 1.0 / result.fps, "pyramid_m": s.pyramid_m, "solver": s.solver,
                         "margin": s.margin, "settle_steps": s.settle_steps, "grip": dataclasses.asdict(s.grip),
                         "object_contacts": s.object_contacts, "self_contacts": s.self_contacts,
                         "sdf_voxel": s.sdf_voxel if s.object_contacts == "sdf" else None},
            "threads": torch.get_num_threads(), "numerics": numerics_record()}


def prepare_result_dir(out, *, overwrite: bool = False):
    """Validate and claim ``out`` before any work (the synthesis writer's rules: new, empty, or an earlier result
    with ``overwrite``). returns: the writer; raises InputValueError with one line."""
    from ..synthesis.output import ResultWriter

    return ResultWriter(out, overwrite=overwrite)


def write_resynthesis(result: ResynthResult, out=None, *, overwrite: bool = False, writer=None) -> Path:
    """Write the result directory: scene/, hand.xml, solutions/sol_XXX.npz (one per completed rollout, in variant
    order), stats.json (``method: "kry_pai"``, every rollout's status, variant and solution index) last; every file
    atomically. Failed rollouts have no solution file (their frames end at the failed step). returns: the path."""
    writer = writer if writer is not None else prepare_result_dir(out, overwrite=overwrite)
    writer.begin(result, result.scene, [result.hand])
    written = []
    for i, r in enumerate(result.rollouts):
        if r.ok:
            writer.write_solution(len(written), solution_arrays(result, i), result.scene.name)
            written.append(i)
    return writer.complete(_stats(result, written))


def _progress_line(msg: str) -> None:
    print(f"torchhand: {msg}", file=sys.stderr, flush=True)
