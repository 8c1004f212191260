"""Mounting a robot hand on a scene's wrist track without tuning: a small search over the mount's offset and
rotation that maximises how much of the object's surface the fingertip pads can reach along the track.

A scene's wrist track was made for some hand; a robot hand mounted by its hand-frame rule
(:mod:`torchhand.hand.mount`) sits where that rule puts it, which can leave a finger (the Shadow thumb on
``box-turn``) unable to reach the object at all. :func:`fit_mount` moves the model on the track by ``M`` (a shift
and a rotation in the hand frame, :func:`torchhand.hand.mount.mount_transform`) chosen by:

* **reach**: at ``n_frames`` frames spread over the scene, the fraction ``A_f`` of ``surface_samples`` object
  surface points (fixed generator) that finger ``f``'s pad touches facing them (:func:`pad_workspace`: pad voxels
  of 4 mm and facing directions within 50 degrees, over random finger poses), capped at ``REACH_ENOUGH`` and scaled
  to 1 (``s_f = min(A_f / REACH_ENOUGH, 1)``); per frame ``sqrt(s_thumb * s_2)``, ``s_2`` the second largest among
  the other fingers (an opposed grip needs the thumb and two fingers), averaged over the frames (1: every frame);
* **no palm inside the object**: minus ``PALM_PENALTY`` per metre of the deepest penetration of the palm's surface
  samples (links of no finger, at the rest pose) into the object's SDF, averaged over the frames;
* **small moves**: minus ``MOVE_PENALTY`` per centimetre of shift and per 10 degrees of rotation.

Search, deterministic: candidates are ranked by the uncapped score (shifts on a 5 mm grid within +/- 2 cm, then
rotation vectors on a 5 degree grid within +/- 10 degrees at the best shift, then shifts refined on a 2.5 mm grid
around the best); the fit is the first in that order with the best capped score, the unmoved mount first (so a fit
never scores below the rule's mount). The rest pose: "relaxed" where the hand so posed and mounted stays out of the
object at the fit's frames (``REST_CLEARANCE``), else "zero".

Conventions: metres, degrees for the reported rotation vector, column-vector 4x4 transforms.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.objects import sample_surface
from ..geometry.sdf import SDFGrid
from ..hand.mount import load_sidecar, mount_transform, thumb_index, track_hand
from .problem import _code

__all__ = ["MountFit", "fit_mount", "fit_mounts", "REACH_ENOUGH", "PALM_PENALTY", "MOVE_PENALTY"]

REACH_ENOUGH = 0.005
"""A finger reaches enough of the object at a frame when this fraction of its surface lies in its workspace: more
is not better (a grip needs a contact per finger, not a large area; without the cap the fit would centre every
object in the fingers' workspace and pull hands back from tracks made for them)."""
REST_CLEARANCE = 0.002
"""The relaxed rest pose is taken when no surface sample of the hand, so posed and mounted, lies deeper than this
inside the object at the fit's frames (metres)."""
PALM_PENALTY = 30.0
"""Score lost per metre of palm penetration into the object (5 mm costs 0.15 of the score's range 0..1)."""
MOVE_PENALTY = 0.002
"""Score lost per centimetre of shift and per 10 degrees of rotation: among equally good mounts, the least moved."""
_VOXEL = 0.004  # pad-workspace voxel, metres
_FACING_COS = math.cos(math.radians(50.0))  # a pad normal counts for every direction bin within 50 degrees
_BINS = torch.tensor([v for v in itertools.product((-1.0, 0.0, 1.0), repeat=3) if any(v)], dtype=torch.float64)
_BINS = _BINS / _BINS.norm(dim=1, keepdim=True)  # 26 directions


@dataclass(frozen=True)
class MountFit:
    """A fitted mount: side; mount (6 floats: shift metres, rotation vector degrees, hand frame); score and
    score_unmoved (the criterion of the module docstring for the fitted and the rule's mount); reach_unmoved and
    reach (per finger, the mean fraction of the surface samples reachable, (F,) tuples); frames: the frames used."""

    side: str
    mount: tuple
    rest: str
    score: float
    score_unmoved: float
    reach: tuple
    reach_unmoved: tuple
    frames: tuple

    def describe(self) -> str:
        s, r = np.asarray(self.mount[:3]) * 1000, np.asarray(self.mount[3:])
        return (f"mount fit ({self.side}): shift ({s[0]:+.1f}, {s[1]:+.1f}, {s[2]:+.1f}) mm, rotation "
                f"({r[0]:+.1f}, {r[1]:+.1f}, {r[2]:+.1f}) deg, rest {self.rest}; reach score "
                f"{self.score_unmoved:.3f} -> {self.score:.3f}")


def fit_mounts(scene, *, frames: tuple[int, int] | None = None):
    """``(scene with fitted mounts, fits)``: :func:`fit_mount` for every hand track with a hand file, no ``mount``
    of its own and no ``[mount]`` in a sidecar (those win); other tracks are left as they are."""
    fits, hands = [], []
    for track in scene.hands:
        if track.model == "default" or track.mount is not None or load_sidecar(track.model).get("mount"):
            hands.append(track)
            continue
        fit = fit_mount(scene, track.side, frames=frames)
        fits.append(fit)
        hands.append(dataclasses.replace(track, mount=fit.mount, rest=fit.rest))
    return dataclasses.replace(scene, hands=tuple(hands)), tuple(fits)


def fit_mount(scene, side: str, *, frames: tuple[int, int] | None = None, n_frames: int = 8,
              surface_samples: int = 600) -> MountFit:
    """The mount and rest pose of ``scene``'s ``side`` hand (module docstring), over ``frames`` (start, stop) of
    the scene (default all), ``n_frames`` of them evenly spread."""
    track = scene.hand(side)
    a, b = frames if frames is not None else (0, scene.T)
    ks = tuple(sorted({int(round(v)) for v in np.linspace(a, b - 1, min(n_frames, b - a))}))
    ctx = _context(scene, track, ks, surface_samples)
    cands = np.stack([np.zeros(6)] + [c for c, _ in _rank(ctx)])
    scores = _score(ctx, cands, REACH_ENOUGH)
    k = int(np.argmax(scores))                                  # the first of the best, the unmoved mount first
    reach = _areas(ctx, cands[[k, 0]]).mean(1)                  # (2, F)
    return MountFit(side=side, mount=tuple(float(v) for v in cands[k]), rest=_rest(scene, track, cands[k], ks, ctx.sdf),
                    score=float(scores[k]), score_unmoved=float(scores[0]), reach=tuple(reach[0].tolist()),
                    reach_unmoved=tuple(reach[1].tolist()), frames=ks)


def _context(scene, track, ks: tuple, surface_samples: int) -> "_Ctx":
    hand = track_hand(dataclasses.replace(track, mount=None))
    gen = torch.Generator().manual_seed(0)
    codes = pad_workspace(hand, gen)
    surf, nrm = sample_surface(scene.object.mesh, surface_samples, gen, dtype=torch.float64)
    O = scene.object_pose.double()[list(ks)]
    W = track.wrist_pose.double()[list(ks)]
    H = torch.linalg.inv(W) @ O  # track hand frame <- object
    pts = torch.einsum("kij,sj->ksi", H[:, :3, :3], surf) + H[:, None, :3, 3]
    inward = -torch.einsum("kij,sj->ksi", H[:, :3, :3], nrm)
    sdf = SDFGrid.from_mesh(scene.object.mesh, 0.003, progress=False, dtype=torch.float64)
    return _Ctx(codes, pts, inward, _palm_points(hand), torch.linalg.inv(O) @ W, sdf, thumb_index(hand))


def _rest(scene, track, mount: np.ndarray, ks: tuple, sdf: SDFGrid) -> str:
    """"relaxed" when the hand at its relaxed rest pose, so mounted, stays out of the object at the frames ``ks``
    (no surface sample deeper than ``REST_CLEARANCE``), else "zero"; a sidecar's ``[rest] pose`` wins."""
    named = load_sidecar(track.model).get("rest", {}).get("pose") if track.model != "default" else None
    if named:
        return named
    hand = track_hand(dataclasses.replace(track, mount=tuple(mount), rest="relaxed"))
    O = scene.object_pose.double()[list(ks)]
    W = track.wrist_pose.double()[list(ks)]
    T = hand.forward_kinematics(hand.q_rest[None].double().expand(len(ks), -1), W)  # (K, L, 4, 4)
    G = torch.linalg.inv(O)[:, None] @ T  # object <- link
    lk = hand.sample_link
    pts = torch.einsum("kpij,pj->kpi", G[:, lk, :3, :3], hand.sample_points.double()) + G[:, lk, :3, 3]
    depth = float((-sdf.query(pts)).max())
    return "relaxed" if depth <= REST_CLEARANCE else "zero"


def _rank(ctx: "_Ctx") -> list:
    """Candidate mounts (6,) with their uncapped reach score, best first: shifts on a 5 mm grid within +/- 2 cm,
    rotation vectors on a 5 degree grid within +/- 10 degrees at the best shift, shifts refined by 2.5 mm."""
    seen = [(np.zeros(6), float(_score(ctx, np.zeros((1, 6)))[0]))]
    best = seen[0]
    step = 0.005
    shifts = np.array(list(itertools.product(np.arange(-4, 5) * step, repeat=3)))
    for stage in range(3):
        if stage == 0:
            cands = np.concatenate([shifts, np.zeros_like(shifts)], 1)
        elif stage == 1:
            rots = np.array(list(itertools.product(np.arange(-2, 3) * 5.0, repeat=3)))
            cands = np.concatenate([np.repeat(best[0][None, :3], len(rots), 0), rots], 1)
        else:
            fine = np.array(list(itertools.product(np.arange(-1, 2) * step / 2, repeat=3)))
            cands = np.concatenate([best[0][None, :3] + fine, np.repeat(best[0][None, 3:], len(fine), 0)], 1)
        scores = _score(ctx, cands)
        seen.extend(zip(cands, scores.tolist()))
        k = int(np.argmax(scores))
        if scores[k] > best[1]:
            best = (cands[k], float(scores[k]))
    return sorted(seen, key=lambda cs: -cs[1])


@dataclass(frozen=True)
class _Ctx:
    codes: list  # per finger, pad-workspace codes (voxel and facing direction, model hand frame)
    pts: torch.Tensor  # (K, S, 3) surface samples in the track's hand frame
    inward: torch.Tensor  # (K, S, 3) their inward normals (the direction a pad touching them faces)
    palm: torch.Tensor  # (H, 3) palm samples in the model's hand frame, at rest
    obj_from_hand: torch.Tensor  # (K, 4, 4) object frame <- track hand frame
    sdf: SDFGrid
    thumb: int | None


def _palm_points(hand, most: int = 256) -> torch.Tensor:
    """Surface samples of the links of no finger (the palm and what carries it) at the rest pose, hand frame; at
    most ``most`` of them, evenly strided."""
    T = hand.forward_kinematics(hand.q_rest[None].double())[0]
    idx = (hand.link_finger[hand.sample_link] < 0).nonzero().squeeze(-1)
    idx = idx[:: max(1, math.ceil(idx.numel() / most))]
    lk = hand.sample_link[idx]
    return torch.einsum("hij,hj->hi", T[lk, :3, :3], hand.sample_points[idx].double()) + T[lk, :3, 3]


def pad_workspace(hand, generator: torch.Generator, samples: int = 16384) -> list[torch.Tensor]:
    """Per finger, the sorted codes of (voxel of the fingertip pad, direction bin the pad faces) over random finger
    poses within the limits, in the hand frame: a pad at a voxel facing within 50 degrees of a bin's direction
    marks that bin. The pad faces against its nail normal."""
    q = hand.random_q(samples, generator)
    T = hand.forward_kinematics(q)
    R, dl = T[:, hand.distal_link, :3, :3], hand.distal_link
    tips = (R @ hand.fingertip[None, :, :, None]).squeeze(-1) + T[:, dl, :3, 3]
    faces = -(R @ hand.nail_normal[None, :, :, None]).squeeze(-1)  # (N, F, 3)
    out = []
    for f in range(hand.num_fingers):
        vox = _code(torch.floor(tips[:, f] / _VOXEL).long())  # (N,)
        ok = (faces[:, f].double() @ _BINS.T) > _FACING_COS  # (N, 26)
        n, b = ok.nonzero(as_tuple=True)
        out.append(torch.unique(vox[n] * 32 + b))
    return out


def _pad_reach(cell: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
    """Whether surface points are touched by a pad facing them: their (voxel, nearest direction bin) code ``cell``
    (…,) long (:func:`_cells`) is in ``codes``. (…,) bool."""
    pos = torch.searchsorted(codes, cell.reshape(-1)).clamp_max(codes.numel() - 1)
    return (codes[pos] == cell.reshape(-1)).reshape(cell.shape)


def _cells(local: torch.Tensor, inward: torch.Tensor) -> torch.Tensor:
    """The (voxel, nearest direction bin) code of surface points (…, 3) with inward normals (…, 3), model hand
    frame, as :func:`_pad_reach` looks them up. (…,) long."""
    return _code(torch.floor(local / _VOXEL).long()) * 32 + (inward @ _BINS.T).argmax(-1)


def _transforms(cands: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.stack([mount_transform(c) for c in cands]))


def _areas(ctx: _Ctx, cands: np.ndarray) -> torch.Tensor:
    """(C, K, F): per candidate mount (C, 6) and frame, the fraction of surface samples each finger's pad reaches."""
    M_inv = torch.linalg.inv(_transforms(cands))  # model hand frame <- track hand frame
    local = torch.einsum("cij,ksj->cksi", M_inv[:, :3, :3], ctx.pts) + M_inv[:, None, None, :3, 3]
    inward = torch.einsum("cij,ksj->cksi", M_inv[:, :3, :3], ctx.inward)
    cell = _cells(local, inward)                                  # the same for every finger
    return torch.stack([_pad_reach(cell, c).double().mean(2) for c in ctx.codes], -1)


def _score(ctx: _Ctx, cands: np.ndarray, cap: float | None = None) -> np.ndarray:
    """The score of the module docstring per candidate mount (C, 6), reach capped at ``cap`` (None: uncapped)."""
    M = _transforms(cands)
    A = _areas(ctx, cands)  # (C, K, F)
    th = ctx.thumb if ctx.thumb is not None else int(A.mean((0, 1)).argmax())
    others = torch.cat([A[..., :th], A[..., th + 1:]], -1)
    second = others.sort(-1, descending=True).values[..., min(1, others.shape[-1] - 1)]
    sat = (lambda a: (a / cap).clamp_max(1.0)) if cap else (lambda a: a)
    reach = torch.sqrt(sat(A[..., th]) * sat(second)).mean(1)  # (C,)
    G = ctx.obj_from_hand[None] @ M[:, None]  # (C, K, 4, 4) object <- model hand frame
    palm = torch.einsum("ckij,hj->ckhi", G[..., :3, :3], ctx.palm) + G[..., None, :3, 3]
    depth = (-ctx.sdf.query(palm.reshape(1, -1, 3)).reshape(palm.shape[:3])).clamp_min(0).amax(-1).mean(1)
    move = np.linalg.norm(cands[:, :3], axis=1) / 0.01 + np.linalg.norm(cands[:, 3:], axis=1) / 10.0
    return (reach - PALM_PENALTY * depth).numpy() - MOVE_PENALTY * move
