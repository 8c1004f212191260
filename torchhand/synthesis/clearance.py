"""How far each hand's palm stays from the object along its wrist track: a wrist track that drives the palm into
the object (a swapped-in object too large, an object moved toward the palm) leaves the search nothing to find,
whatever the fingers do.

The palm is every link that belongs to no finger (``HandModel.link_finger < 0``) and the first link of every
four-link finger (its metacarpal, inside the palm: the palm's surface between wrist and knuckles), posed at the rest
pose; each capsule axis is sampled at most ``spacing`` apart, and its clearance is the smallest signed distance of
those points to the object (the problem's SDF) less the capsule's radius: negative where the palm is inside.
"""

from __future__ import annotations

import torch

from .problem import SynthesisProblem

__all__ = ["palm_links", "palm_clearance", "describe_palm"]


def palm_links(hand) -> torch.Tensor:
    """The palm's links (module docstring), (P,) long."""
    fl = hand.finger_links
    meta = fl[(fl >= 0).all(-1), 0]
    return torch.cat([(hand.link_finger < 0).nonzero().squeeze(-1), meta]).unique()


def palm_clearance(problem: SynthesisProblem, spacing: float = 0.002) -> torch.Tensor:
    """Palm clearance per hand and frame, (H, T), metres (module docstring)."""
    out = []
    for h, hand in enumerate(problem.hands):
        links = palm_links(hand)
        links = links[hand.capsule_radius[links] > 0]
        if links.numel() == 0:
            out.append(torch.full((problem.T,), float("inf"), dtype=problem.dtype, device=problem.device))
            continue
        poses = hand.forward_kinematics(hand.q_rest.expand(problem.T, -1), problem.root[h])[:, links]   # (T, P, 4, 4)
        a, b = hand.capsule_a[links], hand.capsule_b[links]
        n = int(((b - a).norm(dim=-1).max() / spacing).ceil()) + 1
        s = torch.linspace(0.0, 1.0, n, dtype=a.dtype, device=a.device)
        local = a[:, None] + s[None, :, None] * (b - a)[:, None]                                      # (P, n, 3)
        world = (poses[:, :, None, :3, :3] @ local[None, ..., None]).squeeze(-1) + poses[:, :, None, :3, 3]
        inv = problem.object_inv
        obj = (inv[:, None, None, :3, :3] @ world[..., None]).squeeze(-1) + inv[:, None, None, :3, 3]
        sd = problem.sdf.query(obj.reshape(1, -1, 3).to(problem.dtype)).reshape(problem.T, links.numel(), n)
        out.append((sd - hand.capsule_radius[links][None, :, None].to(sd)).amin(dim=(1, 2)))
    return torch.stack(out)


def describe_palm(problem: SynthesisProblem) -> str | None:
    """One line naming the hands whose palm goes into the object, how deep and at which frames; None if none."""
    gap = palm_clearance(problem)
    lines = []
    for h, side in enumerate(problem.sides):
        bad = (gap[h] < 0).nonzero().squeeze(-1).tolist()
        if bad:
            lines.append(f"the {side} palm goes up to {-1e3 * float(gap[h].min()):.1f} mm into the object at "
                         f"{len(bad)} frame(s) ({bad[0]}-{bad[-1]}) on its fixed wrist track")
    return "; ".join(lines) or None
