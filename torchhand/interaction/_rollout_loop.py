"""The resynthesis loop: B rollouts stepped together over T frames (stages 4-6 of :mod:`torchhand.interaction.resynth`).

Per frame k: the compliance C(t_k) scaled by each rollout's grip, one batched
:func:`~torchhand.interaction.step.quasi_static_step` towards the reference of frame k + 1, the frame's
:class:`~torchhand.interaction._rollout_record.FrameRecord`, the rollouts whose LCP failed marked (they stop
counting), and the grip update (:mod:`torchhand.interaction.grip`). Units: metres, seconds, radians, newtons.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import replace

import torch

from ..errors import InputValueError
from ..kernels.status import SolverStatus
from ._contacts import BODY_OBJECT, Contacts, TablePlane
from ._rollout_record import FrameRecord, RolloutRecord
from .grip import GripSettings, grip_update, init_grip, path_mask
from .reach import reach_update, touching_fingers
from .step import StepObject, StepReport, StepSettings, StepState, initial_state, quasi_static_step

__all__ = ["simulate"]

_CONVERGED = int(SolverStatus.CONVERGED)


def _start(hand, obj: StepObject, env: TablePlane | None, theta_r: torch.Tensor, root_r: torch.Tensor,
           object_pose0: torch.Tensor, settings: StepSettings) -> StepState:
    """The state at the frame-0 reference; raises InputValueError when the object starts deep inside the hand."""
    state = initial_state(hand, theta_r[:, 0], root_r[:, 0], object_pose=object_pose0, obj=obj, env=env,
                          settings=settings)
    c = state.contacts
    if bool(((state.contacts.separation < -0.005) & state.contacts.mask & (c.body == BODY_OBJECT)).any()):
        raise InputValueError("the object starts more than 5 mm inside the hand at frame 0; move the object or start "
                              "the interaction from an open hand")
    return state


def _slot_forces(rep: StepReport, sc: Contacts, B: int):
    """f^{k+1} per slot (B, N, 3), newtons, and each slot's friction coefficient (B, N) (0 on inactive slots)."""
    f = torch.einsum("bnrk,bnk->bnr", rep.D, rep.beta)
    mu = rep.lcp.mu.new_zeros(B, sc.mask.shape[1]).scatter(1, rep.order, rep.lcp.mu)
    return f, mu


def _state_fields(state: StepState, Ck: torch.Tensor) -> dict:
    """The FrameRecord fields of the state itself, on the CPU: q, theta_r, root, object pose, the compliance Ck
    applied, its contact slots and theta_err."""
    sc = state.contacts
    cpu = lambda x: x.detach().cpu()  # noqa: E731
    return dict(q=cpu(state.q), theta_r=cpu(state.theta_r), root=cpu(state.root), object_pose=cpu(state.object_pose),
                C=cpu(Ck), points=cpu(sc.points), d0=cpu(sc.d0), sep=cpu(sc.separation), body_mask=cpu(sc.mask),
                theta_err=cpu(state.theta_err.abs().amax(-1)))


def _frame(state: StepState, rep: StepReport, Ck: torch.Tensor, f: torch.Tensor, mu: torch.Tensor) -> FrameRecord:
    """Frame k on the CPU: the state at t_k and what step k solved."""
    return FrameRecord(**_state_fields(state, Ck), forces=f.detach().cpu(), lam=rep.lam.detach().cpu(),
                       mu=mu.detach().cpu(), status=rep.status.detach().cpu(), residual=rep.residual.detach().cpu(),
                       joint_clamp=rep.joint_clamp.detach().cpu())


def simulate(hand, obj: StepObject, env: TablePlane | None, theta_r: torch.Tensor, root_r: torch.Tensor,
             C: torch.Tensor, object_pose0: torch.Tensor, *, settings: StepSettings,
             grip: GripSettings = GripSettings(), settle_steps: int = 0, progress=None,
             reach: tuple | None = None, close_open: tuple = ()) -> RolloutRecord:
    """Run B rollouts over T frames (module docstring of :mod:`torchhand.interaction.resynth`, stages 4-6).

    hand: HandModel (the rollouts' dtype); obj: :class:`StepObject` (per-rollout ``masses``/``mus`` allowed);
    env: the table or None; theta_r: (B, T, D) rad; root_r: (B, T, 4, 4); C: (B, T, 6 + D) (variant scales applied);
    object_pose0: (B, 4, 4); settings: :class:`StepSettings`; grip: :class:`GripSettings`; progress: callable(str);
    reach: (:class:`~torchhand.interaction.reach.ReachPlan` over the T steps, its
    :class:`~torchhand.interaction.reach.ReachSettings`) or None; close_open: the frames whose finger references the
    hand moves through before the first frame, the root held at frame 0's (the paper's settle: closing and opening
    again), then ``settle_steps`` steps at frame 0's reference
    returns: :class:`~torchhand.interaction._rollout_record.RolloutRecord`: per-frame tensors (CPU), per-rollout
        ``failed_step`` (B,) (-1: completed), ``failed_status`` (B,) int8, ``grip_events`` list of
        (rollout, frame, link), ``onset`` (B,); fields also read by key (``rec["q"]``)
    """
    from threadpoolctl import threadpool_limits

    # the per-rollout LCPs are small dense NumPy solves and the step's tensors are small: one BLAS thread and one
    # torch thread, because several threads on such problems only contend (on a busy 2-core machine: the LCP 6x
    # slower with two BLAS threads, the whole step 7.8x with two torch threads; on a quiet one two torch threads
    # gained 7 % at 16 rollouts and nothing at one), and the results must not depend on the cores
    with threadpool_limits(limits=1, user_api="blas"), _one_torch_thread():
        return _simulate(hand, obj, env, theta_r, root_r, C, object_pose0, settings, grip, settle_steps, progress,
                         reach, tuple(close_open))


@contextlib.contextmanager
def _one_torch_thread():
    """torch's intra-op threads held at one inside the block, then restored."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def _last_frame(state: StepState, before: FrameRecord, Ck: torch.Tensor) -> FrameRecord:
    """The last frame T - 1: the state as it is, with the forces it holds (f^{T-1}, solved by the step into it, which
    the hand's pose is in equilibrium with), carried on its own contact slots. There is no step out of it: frame
    T - 1 of the interaction has no next frame to move to, and the checker's balance at the last frame takes the
    acceleration of the frame before, which these forces produced. Its solver status, residual and slips are the
    step's into it (``before``, frame T - 2)."""
    return replace(before, **_state_fields(state, Ck), forces=state.forces.detach().cpu(),
                   joint_clamp=torch.zeros_like(before.joint_clamp))


def _simulate(hand, obj, env, theta_r, root_r, C, object_pose0, settings, grip, settle_steps, progress, reach,
              close_open):
    B, T, D = theta_r.shape
    if T < 2:
        raise InputValueError(f"simulate: theta_r needs at least 2 frames, got {T}")
    like = theta_r
    state = _start(hand, obj, env, theta_r, root_r, object_pose0, settings)
    c = state.contacts
    hand_obj = (c.body == BODY_OBJECT).cpu()
    for j in close_open:
        state, _ = quasi_static_step(state, hand, theta_r[:, j], root_r[:, 0], C[:, 0], obj, env, settings)
    for _ in range(settle_steps):
        state, _ = quasi_static_step(state, hand, theta_r[:, 0], root_r[:, 0], C[:, 0], obj, env, settings)
    paths = path_mask(hand, c.link)
    gs = init_grip(B, 6 + D, c.mask.shape[1], settings.h, grip, like)
    alive = torch.ones(B, dtype=torch.bool)
    failed_step = torch.full((B,), -1, dtype=torch.long)
    failed_status = torch.zeros(B, dtype=torch.int8)
    frames, events, walls = [], [], []
    offset = like.new_zeros(B, D)
    t0 = time.perf_counter()
    for k in range(T - 1):
        t_k = time.perf_counter()
        Ck = C[:, k] * gs.scale
        new, rep = quasi_static_step(state, hand, theta_r[:, k + 1] + offset, root_r[:, k + 1], Ck, obj, env, settings)
        f, mu = _slot_forces(rep, state.contacts, B)
        frames.append(_frame(state, rep, Ck, f, mu))
        bad = alive & (rep.status.cpu() != _CONVERGED)
        if bool(bad.any()):
            failed_step[bad] = k
            failed_status[bad] = rep.status.cpu()[bad]
            alive &= ~bad
        gs, ev = grip_update(gs, k, f, rep.lam, state.contacts, mu, paths, grip)
        events += [e for e in ev if bool(alive[e[0]])]
        if reach is not None:
            plan, rs = reach
            offset = reach_update(offset, k, plan, touching_fingers(f, state.contacts, hand, rs.min_force),
                                  settings.h, rs)
        state = new
        walls.append(time.perf_counter() - t_k)
        if progress is not None and (k + 1) % 50 == 0:
            el = time.perf_counter() - t0
            progress(f"step {k + 1}/{T - 1}: {1e3 * el / (k + 1):.1f} ms/step, {int(alive.sum())}/{B} rollouts "
                     "running")
    frames.append(_last_frame(state, frames[-1], C[:, T - 1] * gs.scale))
    return RolloutRecord.from_frames(
        frames, failed_step=failed_step, failed_status=failed_status, grip_events=events, onset=gs.onset.cpu(),
        slot_link=c.link.cpu(), slot_body=c.body.cpu(), hand_obj=hand_obj,
        step_time_s=(time.perf_counter() - t0) / max(T - 1, 1), step_times_s=tuple(walls))
