"""Result directories of ``torchhand synthesize`` (the format other tools read; see ``docs/synthesis.md``).

``DIR/scene/`` (the scene as exported), ``DIR/hand.xml`` (first hand, MJCF; ``hand_left.xml`` for the second of two),
``DIR/stats.json`` (Ye & Liu Table 1 columns and more) and ``DIR/solutions/sol_000.npz``, ... with, per solution
(T frames, D finger joints, K <= 32 contacts, E table contacts):

    q (T, D) radians, joint_names (D,); root_pose (T, 4, 4); object_pose (T, 4, 4); fps ()
    contact_mask (T, K), contact_link (T, K) (index into contact_link_name, -1 = padding), contact_link_name,
    contact_point (T, K, 3) world, contact_normal (T, K, 3) into the object, contact_force (T, K, 3) hand on object,
    contact_sliding (T, K); env_contact_mask (T, E), env_contact_point (T, E, 3), env_contact_force (T, E, 3);
    guiding (T, 5); strategy; friction (); reconstructed ()

With two hands ``q``, ``root_pose`` and ``guiding`` are the right hand's, ``q_right``/``q_left``,
``root_pose_right``/``root_pose_left`` and ``guiding_right``/``guiding_left`` hold both, and the link-name table
is prefixed ``right/`` and ``left/``. Every file is written to a temporary name in its folder and moved into place
with ``os.replace``; nothing already in DIR is touched before the new content is complete.
"""

from __future__ import annotations

import io
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from ..errors import InputValueError
from ..hand.mjcf import hand_to_mjcf
from ..scene import Scene
from .node_test import contact_slots
from .pipeline import SynthesisResult, diversity

__all__ = ["MAX_CONTACTS", "write_result", "solution_arrays", "stats_dict"]

MAX_CONTACTS = 32
"""K, the most hand contacts written per frame."""


def _atomic_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def solution_arrays(result: SynthesisResult, index: int, strategy: str) -> dict:
    """The npz arrays of solution ``index`` (see the module docstring)."""
    p = result.problem
    sol = result.solutions[index]
    T = sol.q.shape[0]
    H = p.H
    hands = p.hands
    names = []
    for h, hand in enumerate(hands):
        names += [(f"{p.sides[h]}/" if H > 1 else "") + n for n in hand.link_names]
    mask = sol.c_mask.cpu()
    counts = mask.sum(-1)
    K = int(counts.max()) if T else 0
    if K > MAX_CONTACTS:
        raise InputValueError(f"a frame has {K} hand contacts, more than the {MAX_CONTACTS} the format holds")
    order = torch.sort((~mask).to(torch.int8), dim=-1, stable=True).indices[:, :K]      # contacts first
    take = lambda x: torch.gather(x.cpu(), 1, order[..., None].expand(-1, -1, x.shape[-1]) if x.dim() == 3 else order)
    c_mask = torch.gather(mask, 1, order)
    slot_hand, slot_link = contact_slots(p)
    offsets = torch.tensor([0] + [hd.num_links for hd in hands[:-1]]).cumsum(0)
    slot_name = (offsets[slot_hand.cpu()] + slot_link.cpu())                              # index into the names
    link = torch.where(c_mask, slot_name[order], torch.full_like(order, -1))
    f = lambda x: x.detach().double().cpu().numpy()
    m3 = c_mask[..., None].double()
    out = {
        "joint_names": np.array(hands[0].joint_names),
        "object_pose": f(p.object_pose), "fps": np.array(p.fps),
        "contact_mask": c_mask.numpy(), "contact_link": link.numpy(), "contact_link_name": np.array(names),
        "contact_point": f(take(sol.c_point) * m3), "contact_normal": f(take(sol.c_normal) * m3),
        "contact_force": f(take(sol.c_force) * m3),
        "contact_sliding": torch.gather(sol.sliding.cpu(), 1, order).numpy() & c_mask.numpy(),
        "env_contact_mask": p.env.mask.cpu().numpy(), "env_contact_point": f(p.env.points),
        "env_contact_force": f(sol.env_force * p.env.mask[..., None].to(sol.env_force.dtype)),
        "strategy": np.array(strategy), "friction": np.array(p.friction),
        "reconstructed": np.array(bool(sol.reconstructed)),
    }
    first = p.sides.index("right") if "right" in p.sides else 0
    out["q"] = f(sol.q[:, first])
    out["root_pose"] = f(p.root[first])
    out["guiding"] = sol.guiding[:, first].cpu().numpy()
    if H > 1:
        for h, side in enumerate(p.sides):
            out[f"q_{side}"] = f(sol.q[:, h])
            out[f"root_pose_{side}"] = f(p.root[h])
            out[f"guiding_{side}"] = sol.guiding[:, h].cpu().numpy()
    return out


def stats_dict(result: SynthesisResult, scene: Scene, *, strategy: str, seed: int) -> dict:
    """stats.json: the paper's Table 1 columns for the run and more (see ``docs/synthesis.md``)."""
    st = result.stats
    found = len(result.solutions) + result.excluded
    search_s = result.timings.get("search_s", st.time_s)
    return {
        "scene": scene.name, "epsilon": result.settings.epsilon, "T": scene.T, "time_s": result.timings.get("total_s"),
        "solutions": len(result.solutions), "paths_found": found, "excluded": result.excluded,
        "dead_ends": st.dead_ends, "total_frames": st.nodes_tested, "success_frames": st.success_frames,
        "success_ratio": st.success_frames / st.nodes_tested if st.nodes_tested else 0.0,
        "solution_ratio": found / (found + st.dead_ends) if found + st.dead_ends else 0.0,
        "nodes_tested": st.nodes_tested, "nodes_per_second": st.nodes_tested / search_s if search_s > 0 else 0.0,
        "rejections": dict(st.rejections), "diversity_m": _finite(diversity(result.solutions)),
        "reconstructed": [bool(s.reconstructed) for s in result.solutions],
        "restarts": st.restarts, "deepest_frame": st.deepest_frame, "strategy": strategy, "seed": seed,
        "timings_s": result.timings, "trees": result.settings.trees, "candidates": result.settings.candidates,
        "slide_speed": result.node_settings.slide_speed,
        "rejections_by_frame": [list(r) for r in st.rejections_by_frame],
    }


def _finite(x: float):
    return None if x is None or not math.isfinite(x) else x


def write_result(result: SynthesisResult, scene: Scene, out: str | os.PathLike, *, strategy: str, seed: int) -> Path:
    """Write the result directory (see the module docstring). Returns its path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene.export(out / "scene", overwrite=True)
    p = result.problem
    for h, hand in enumerate(p.hands):
        name = "hand.xml" if h == 0 else f"hand_{p.sides[h]}.xml"
        _atomic_bytes(out / name, hand_to_mjcf(hand.to("cpu", torch.float64)).encode())
    sol_dir = out / "solutions"
    sol_dir.mkdir(exist_ok=True)
    for i in range(len(result.solutions)):
        buf = io.BytesIO()
        np.savez_compressed(buf, **solution_arrays(result, i, strategy))
        _atomic_bytes(sol_dir / f"sol_{i:03d}.npz", buf.getvalue())
    for old in sol_dir.glob("sol_*.npz"):
        if old.stem[4:].isdigit() and int(old.stem[4:]) >= len(result.solutions):
            old.unlink()                      # solutions of an earlier run beyond this one's count
    stats = stats_dict(result, scene, strategy=strategy, seed=seed)
    _atomic_bytes(out / "stats.json", (json.dumps(stats, indent=2) + "\n").encode())
    return out
