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
   starts at the reference's frame 0. With ``close_open`` the object is first pushed to an improved start as the
   paper does (the grasping motion until every finger pushes and back); then ``settle_steps`` steps at the frame-0
   reference let it come to rest on the table.
4. Steps k -> k + 1 (§7.1): contacts of the hand with the object (each link's capsule against the exact mesh, the
   geometry ``torchhand check`` measures; ``object_contacts="sdf"`` for a grid instead) and the table, of the object
   with the table (object-plane slots, an extension: see :mod:`.step`) and between fingers (finger-finger slots, an
   extension, ``self_contacts``); joint limits clamp theta^{k+1} (reported per frame); the LCP by Lemke's method (one
   rollout) or the batched projected Gauss-Seidel with Lemke for stragglers (several); object integration; contact
   update.
5. Grip adjustment (§8.1, :mod:`.grip`): the compliance of each rollout is scaled down on slip.
6. A rollout whose LCP is not solved at step k stops there (its status names the step); the others go on.

Frame k < T - 1 of a rollout holds the state at t_k (q, root, object pose, contact points and normals) and the
contact forces f^{k+1} solved at step k (the last frame, which has no step out of it, the forces of the step into
it), which act on the object between t_k and t_{k+1} (the explicit-in-position,
implicit-in-force discretisation of §7.1.2), so that the second difference of the object's positions around frame
k matches the forces stored at frame k. The written contact point of a hand contact is on the object surface
(the hand point moved back along the normal by its separation).

Units: metres, seconds, radians, newtons, kilograms; compliance rad/(N m) (root linear m/N).

Layout: this module sets a scene and an interaction up and runs them; the interaction file is
:mod:`._interaction_file`, settings, variants and results :mod:`._resynth_types`, the rollout loop (stages 4-6)
:mod:`._rollout_loop`, its per-frame record and the typed rollout made from it :mod:`._rollout_record`, the result
directory :mod:`._resynth_output`.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputValueError, UnknownNameError
from ._contacts import TablePlane, support_points
from ._interaction_file import Interaction, load_interaction, save_interaction
from ._resynth_output import prepare_result_dir, solution_arrays, write_resynthesis
from ._resynth_types import ResynthResult, ResynthSettings, Rollout, RolloutStatus, Variant, expand_variants
from ._rollout_loop import simulate
from ._rollout_record import hold_frame, object_slip, rollout_result
from .reach import reach_plan
from .step import StepObject, StepSettings, displace_root

__all__ = ["Interaction", "load_interaction", "save_interaction", "Variant", "expand_variants", "ResynthSettings",
           "RolloutStatus", "Rollout", "ResynthResult", "simulate", "resynthesize", "object_slip",
           "solution_arrays", "write_resynthesis", "prepare_result_dir"]


def _resample(inter: Interaction, h: float):
    """Reference at t_k = k h over the interaction's duration: theta_r, root coordinates (linear), C (held). A last
    step within a millionth of a step of the end counts (h given in decimals, 0.004166666667 for 1/240 s, keeps the
    last frame)."""
    T = int(np.floor(inter.duration / h + 1e-6)) + 1
    t = np.arange(T) * h * inter.fps
    i0 = np.clip(np.floor(t + 1e-9).astype(int), 0, inter.T - 1)
    i1 = np.minimum(i0 + 1, inter.T - 1)
    w = (t - i0)[:, None]
    lerp = lambda x: (1 - w) * x[i0] + w * x[i1]
    return lerp(inter.theta_r), lerp(inter.root_theta_r), inter.C[i0]


def _reference_plan(inter: Interaction, hand, h: float, theta_r: np.ndarray, settings: ResynthSettings):
    """The reach plan of the interaction at the steps (which fingers the reference pushes with, and where), for
    ``--reach`` and ``--close-open``; None when neither is on. theta_r: the reference at the steps, (T, D)."""
    wanted = [flag for flag, on in (("--reach", settings.reach.enabled), ("--close-open", settings.close_open)) if on]
    if not wanted:
        return None
    if inter.theta is None:
        raise InputValueError(f"{wanted[0]}: the interaction has no 'theta' (the captured coordinates), so it does "
                              "not say which fingers push when; interactions from `capture estimate` and `capture "
                              "from-result` have it")
    theta = _resample(dataclasses.replace(inter, theta_r=inter.theta[:, 6:]), h)[0]
    return reach_plan(hand, theta, theta_r, settings.reach)


def _close_open(plan) -> tuple:
    """The paper's settle (§8.3): the steps of the grasping motion from frame 0 until every finger the interaction
    ever pushes with pushes (or, if never all at once, the first step with the most of them), then back to frame 0."""
    pushes = plan.pushes.numpy()
    k = int(np.argmax((pushes & pushes.any(0)).sum(1)))
    return tuple(range(1, k + 1)) + tuple(range(k - 1, -1, -1))


def _check_names(inter: Interaction, hand) -> None:
    if tuple(inter.joint_names) != tuple(hand.joint_names):
        missing = [n for n in inter.joint_names if n not in hand.joint_names]
        if missing:
            raise UnknownNameError(f"interaction joint '{missing[0]}' is not a joint of the scene's hand "
                                   f"({len(hand.joint_names)} joints: {', '.join(hand.joint_names[:4])}, ...)")
        raise InputValueError(f"interaction joint_names: the scene's hand has {len(hand.joint_names)} joints in "
                              f"another order; expected {hand.joint_names[:4]}..., got {inter.joint_names[:4]}...")

@dataclass(frozen=True, eq=False)
class _References:
    """The reference at the simulation times t_k = k h, k = 0 .. T - 1 (stage 1).

    theta_r: (T, D), radians, float64; C: held compliance, (T, 6 + D), rad/(N m) (root linear m/N), float64;
    root_r: reference root poses, (T, 4, 4), world, in the rollouts' dtype
    """

    theta_r: np.ndarray
    C: np.ndarray
    root_r: torch.Tensor


def _references(inter: Interaction, scene, h: float, dtype: torch.dtype) -> _References:
    """Stage 1: the interaction resampled at step h; its root coordinates displace ``root_origin`` (or the scene's
    frame-0 wrist pose)."""
    theta_r, root_c, C = _resample(inter, h)
    T = theta_r.shape[0]
    origin = inter.root_origin if inter.root_origin is not None else scene.hands[0].wrist_pose[0].double().numpy()
    root_r = displace_root(torch.from_numpy(origin).to(dtype).expand(T, 4, 4), torch.from_numpy(root_c).to(dtype))
    return _References(theta_r, C, root_r)


def _step_time(inter: Interaction, scene, variants, settings: ResynthSettings) -> float:
    """Check one hand and at least one variant; returns: h, seconds (not longer than the interaction's frame)."""
    if len(scene.hands) != 1:
        raise InputValueError(f"--scene: resynthesis drives one hand, the scene has {len(scene.hands)}")
    if not variants:
        raise InputValueError("variants: at least one rollout is needed")
    h = settings.dt if settings.dt is not None else 1.0 / scene.fps
    if h > 1.0 / inter.fps + 1e-12:
        raise InputValueError(f"--dt: {h:g} s is longer than the interaction's frame time {1 / inter.fps:g} s")
    return h


def _environment(scene, variants: tuple, settings: ResynthSettings, dtype: torch.dtype):
    """Stage 2: the scene's object (or each variant's own) with each variant's mass and friction, and its table (or
    None).

    returns: (:class:`~torchhand.interaction.step.StepObject`, :class:`TablePlane` or None)
    """
    scene.environment.require_plain("resynthesis")
    env = None
    if scene.environment.table:
        env = TablePlane((0.0, 0.0, 1.0), scene.environment.table_height, scene.environment.friction)
    if any(v.object is not None for v in variants):
        return _objects_per_rollout(scene, variants, settings, dtype, env), env
    from ..geometry.sdf import SDFGrid

    rigid = scene.object
    if settings.object_contacts == "mesh":
        sdf, mesh = None, True
    else:
        sdf, mesh = SDFGrid.from_mesh(rigid.mesh, settings.sdf_voxel, progress=False).to("cpu", dtype), None
    sup = support_points(rigid.mesh.vertices, settings.support_points).to(dtype) if env is not None else None
    masses = tuple(rigid.mass if v.mass is None else v.mass for v in variants)
    mus = tuple(scene.friction if v.friction is None else v.friction for v in variants)
    obj = StepObject.from_rigid(rigid, sdf, scene.friction, support=sup, masses=masses, mus=mus, mesh=mesh)
    return obj, env


def _objects_per_rollout(scene, variants: tuple, settings: ResynthSettings, dtype: torch.dtype, env) -> StepObject:
    """One StepObject per variant (its object or the scene's, at its mass and friction); each distinct object's
    exact mesh and support points are made once and shared by the rollouts that use it."""
    from ..check.geometry import object_mesh

    if settings.object_contacts != "mesh":
        raise InputValueError("variants with their own objects need exact-mesh contacts (--object-contacts mesh)")
    shared: dict = {}
    objects = []
    for v in variants:
        rigid = v.object_of(scene)
        if id(rigid) not in shared:
            sup = support_points(rigid.mesh.vertices, settings.support_points).to(dtype) if env is not None else None
            shared[id(rigid)] = (object_mesh(rigid.mesh, float(rigid.mass)), sup)
        mesh, sup = shared[id(rigid)]
        m = rigid.mass if v.mass is None else v.mass
        inertia = np.asarray(rigid.inertia, dtype=np.float64) * (m / rigid.mass)
        objects.append(StepObject(None, float(m), tuple(rigid.com), inertia,
                                  scene.friction if v.friction is None else v.friction, sup, mesh=mesh))
    return StepObject.per_rollout(objects)


def _step_settings(settings: ResynthSettings, scene, h: float, B: int) -> StepSettings:
    """The step's settings; the solver: Lemke in float64 (each rollout's LCP solved as it would be alone), "auto"
    in float32, unless ``settings.solver``."""
    solver = settings.solver or ("lemke" if settings.dtype == torch.float64 else "auto")
    return StepSettings(h=h, pyramid_m=settings.pyramid_m, margin=settings.margin, solver=solver,
                        gravity=tuple(float(x) for x in scene.gravity), geometry="capsules",
                        pgs_max_iters=settings.pgs_max_iters, self_contacts=settings.self_contacts,
                        lemke_warm=settings.lemke_warm, self_mu=float(settings.finger_friction))


def _device(name: str) -> torch.device:
    """The rollouts' device; an InputValueError when it is CUDA and none is available."""
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputValueError(f"--device {name}: no CUDA device is available; use --device cpu")
    return device


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

    t_start = time.perf_counter()
    variants = tuple(variants)
    h = _step_time(inter, scene, variants, settings)
    B = len(variants)
    dtype = settings.dtype
    device = _device(settings.device)
    hand = track_hand(scene.hands[0]).to(device, dtype)
    _check_names(inter, hand)
    ref = _references(inter, scene, h, dtype)
    T = ref.theta_r.shape[0]
    obj, env = _environment(scene, variants, settings, dtype)
    if obj.sdf is not None:
        obj = dataclasses.replace(obj, sdf=obj.sdf.to(device, dtype))
    step = _step_settings(settings, scene, h, B)
    scale = torch.tensor([v.compliance_scale for v in variants], dtype=dtype)
    Ct = (torch.from_numpy(ref.C).to(dtype)[None] * scale[:, None, None]).to(device)
    th = torch.from_numpy(ref.theta_r).to(device, dtype).expand(B, T, -1).contiguous()
    E0 = scene.object_pose[0].to(device, dtype).expand(B, 4, 4).contiguous()
    root_r = ref.root_r.to(device).expand(B, T, 4, 4).contiguous()
    if progress is not None:
        progress(f"resynthesis: {B} rollout(s), {T} steps of {1e3 * h:.2f} ms, solver {step.solver}, on {device}")
    t_sim = time.perf_counter()
    plan = _reference_plan(inter, hand, h, ref.theta_r, settings)
    rec = simulate(hand, obj, env, th, root_r, Ct, E0, settings=step, grip=settings.grip,
                   settle_steps=settings.settle_steps, progress=progress,
                   reach=(plan, settings.reach) if settings.reach.enabled else None,
                   close_open=_close_open(plan) if settings.close_open else ())
    t_sim = time.perf_counter() - t_sim
    hold = hold_frame(ref.root_r.double().numpy(), settings.hold_frame)
    rollouts = tuple(rollout_result(rec, b, v, np.asarray(v.object_of(scene).com, dtype=np.float64), hold)
                     for b, v in enumerate(variants))
    scenes = tuple(_output_scene(scene, r, 1.0 / h) for r in rollouts)
    first = next((i for i, r in enumerate(rollouts) if r.ok), 0)
    timings = {"simulate_s": t_sim, "per_step_ms": 1e3 * rec.step_time_s,
               "median_step_ms": 1e3 * float(np.median(rec.step_times_s)) if rec.step_times_s else None,
               "total_s": time.perf_counter() - t_start}
    return ResynthResult(rollouts, scenes[first], hand, 1.0 / h, timings, settings, inter.source, scenes)


def _output_scene(scene, rollout: Rollout, fps: float):
    """The scene of the result directory: the rollout's object and wrist motion, its mass, fps 1/h."""
    from ..scene import HandTrack

    obj = rollout.variant.object_of(scene)
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


def _progress_line(msg: str) -> None:
    print(f"torchhand: {msg}", file=sys.stderr, flush=True)
