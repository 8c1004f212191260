"""The initial case of Ye & Liu 2012 §4.2: contact patches, uniform samples on them, kinematic pruning.

The contact patches (reachable volume of each fingertip intersected with the moving object's surface) are in
:attr:`SynthesisProblem.patch`. Here their samples are pruned in preprocessing, as the paper does: every sample of
every finger's patch is tried as that finger's guiding point (fingertip pad, IK from the rest pose with
penetration resolution), and only those the finger reaches without penetrating stay. The relative pose of wrist
and object is what decides reachability, so pruning runs on *key frames* only: a frame becomes a key frame when
every hand's wrist pose in the object frame has moved more than ``move_tol`` metres or ``turn_tol`` radians since
the last key frame; other frames use the key frame before them.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..hand.collision import rigid_inverse
from .node_test import Guides, NodeTestSettings, kinematic_verdicts, pad_points
from .problem import SynthesisProblem

__all__ = ["InitialSamples", "prune_patches"]


@dataclass(frozen=True)
class InitialSamples:
    """Pruned patch samples per key frame.

    key_of_frame: key frame index used by each frame, (T,) long
    key_frames:   frame of each key frame, (Kf,) long
    ok:           sample s is a kinematically feasible guiding point of finger f of hand h at key frame k,
                  (Kf, H, F, S) bool (indices into :attr:`SynthesisProblem.surface`)
    """

    key_of_frame: torch.Tensor
    key_frames: torch.Tensor
    ok: torch.Tensor

    def samples(self, t: int, h: int, f: int) -> torch.Tensor:
        """Indices of the feasible samples of finger f of hand h at frame t, (n,) long."""
        return self.ok[int(self.key_of_frame[t]), h, f].nonzero().squeeze(-1)


def _key_frames(problem: SynthesisProblem, move_tol: float, turn_tol: float) -> tuple[torch.Tensor, torch.Tensor]:
    rel = rigid_inverse(problem.object_pose)[None] @ problem.root                  # (H, T, 4, 4) wrist in object
    keys, of = [0], [0]
    for t in range(1, problem.T):
        k = keys[-1]
        d = (rel[:, t, :3, 3] - rel[:, k, :3, 3]).norm(dim=-1).amax()
        c = ((rel[:, t, :3, :3] * rel[:, k, :3, :3]).sum((-1, -2)) - 1) / 2
        ang = torch.arccos(c.clamp(-1, 1)).amax()
        if d > move_tol or ang > turn_tol:
            keys.append(t)
        of.append(len(keys) - 1)
    return torch.tensor(of), torch.tensor(keys)


def prune_patches(problem: SynthesisProblem, generator: torch.Generator, *, per_finger: int = 192,
                  move_tol: float = 0.003, turn_tol: float = 0.05, settings: NodeTestSettings = NodeTestSettings(),
                  progress=None, max_rows: int | None | str = "auto") -> InitialSamples:
    """Prune the patch samples on key frames (see the module docstring).

    per_finger: at most this many patch samples per finger and key frame are tried (a uniform subset from
    ``generator``); all fingers of all hands are tried together, each candidate guiding one sample per finger
    (fingers are independent in the IK, so each finger's verdict is its own). The candidates of every key frame
    are drawn first, then tested: "auto", one call per key frame on a CPU (calls that mix key frames ran 10-25 %
    slower on two cores: the kinematic solve of a call iterates until its slowest row has converged) and all in one
    call on a GPU; a number, calls of at most that many rows; None, one call. A candidate's verdict does not depend
    on the other rows of its call, so the split changes nothing but the time.
    progress: optional callable(n) advanced by the key frames finished, after each call (on a CPU: once per key
    frame).
    """
    of, keys = _key_frames(problem, move_tol, turn_tol)
    H, F, S = problem.H, problem.F, problem.surface.shape[0]
    device = problem.device
    ok = torch.zeros(len(keys), H, F, S, dtype=torch.bool, device=device)
    draws = [_draw(problem, t, per_finger, generator) for t in keys.tolist()]
    rows = [(k, t, sample, active) for k, (t, (sample, active)) in enumerate(zip(keys.tolist(), draws))
            if sample.shape[0]]
    if progress is not None and len(keys) > len(rows):
        progress(len(keys) - len(rows))                     # key frames without a candidate: done
    if not rows:
        return InitialSamples(key_of_frame=of.to(device), key_frames=keys.to(device), ok=ok)
    key = torch.cat([torch.full((s.shape[0],), k, device=device) for k, _, s, _ in rows])
    frame = torch.cat([torch.full((s.shape[0],), t, device=device) for _, t, s, _ in rows])
    sample = torch.cat([s for _, _, s, _ in rows])
    active = torch.cat([a for _, _, _, a in rows])
    n = sample.shape[0]
    if max_rows == "auto" and device.type == "cpu":        # one call per key frame
        split = torch.arange(n, device=device).split([s.shape[0] for _, _, s, _ in rows])
    else:
        max_rows = None if max_rows == "auto" else max_rows
        split = torch.arange(n, device=device).tensor_split(1 if max_rows is None else -(-n // max_rows))
    last = torch.cumsum(torch.tensor([s.shape[0] for _, _, s, _ in rows]), 0) - 1     # each key frame's last row
    fails = []
    for i in split:
        fails.append(_verdicts(problem, frame[i], sample[i], active[i], settings))
        if progress is not None and i.numel():
            progress(int(((last >= int(i[0])) & (last <= int(i[-1]))).sum()))
    fail = torch.cat(fails)
    good = active & ~fail
    for h in range(H):
        for f in range(F):
            sel = good[:, h, f]
            ok[key[sel], h, f, sample[sel, h, f]] = True
    return InitialSamples(key_of_frame=of.to(device), key_frames=keys.to(device), ok=ok)


def _draw(problem: SynthesisProblem, t: int, per_finger: int, generator: torch.Generator):
    """The candidates of key frame t: per finger at most ``per_finger`` of its patch samples (a uniform subset
    from ``generator``), candidate i guiding each finger's i-th; (sample (n, H, F) long, active (n, H, F) bool)."""
    H, F, device = problem.H, problem.F, problem.device
    picks = []
    for h in range(H):
        for f in range(F):
            idx = problem.patch[h, f, t].nonzero().squeeze(-1)
            if idx.numel() > per_finger:
                idx = idx[torch.randperm(idx.numel(), generator=generator)[:per_finger].to(device)]
            picks.append(idx)
    n = max((p.numel() for p in picks), default=0)
    sample = torch.zeros(n, H, F, dtype=torch.long, device=device)
    active = torch.zeros(n, H, F, dtype=torch.bool, device=device)
    for i, idx in enumerate(picks):
        h, f = divmod(i, F)
        m = idx.numel()
        if m:
            sample[:m, h, f] = idx
            active[:m, h, f] = True
    return sample, active


def _verdicts(problem: SynthesisProblem, t: torch.Tensor, sample: torch.Tensor, active: torch.Tensor,
              settings: NodeTestSettings) -> torch.Tensor:
    """The kinematic verdicts of candidates at frames t (n,) guiding the fingers' pads to ``sample`` from the rest
    pose, (n, H, F) bool (True: fails)."""
    n, H, F = sample.shape
    hand0 = problem.hands[0]
    guides = Guides(active=active, link=hand0.distal_link.expand(n, H, F).clone(),
                    local=pad_points(hand0).expand(n, H, F, 3).clone(), obj=problem.surface[sample],
                    slide=torch.zeros(n, H, F, 3, dtype=problem.dtype, device=problem.device))
    q_prev = torch.stack([hd.q_rest for hd in problem.hands]).expand(n, H, -1).clone()
    return kinematic_verdicts(problem, t, q_prev, torch.ones(n, dtype=torch.bool, device=problem.device), guides,
                              settings)
