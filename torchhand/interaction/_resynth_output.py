"""The result directory of a resynthesis (docs/result_format.md): one ``solutions/sol_XXX.npz`` per completed
rollout, with the contract's keys and the Kry & Pai extras, and ``stats.json`` (``method: "kry_pai"``).

The writer is the synthesis writer (:class:`~torchhand.synthesis.output.ResultWriter`): it claims the directory,
writes scene/ and hand.xml, and every file atomically, stats.json last.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from .._numerics import record as numerics_record
from ..errors import InputValueError
from ._resynth_types import ResynthResult

__all__ = ["solution_arrays", "prepare_result_dir", "write_resynthesis"]


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
                         "margin": s.margin, "settle_steps": s.settle_steps, "close_open": s.close_open,
                         "grip": dataclasses.asdict(s.grip),
                         "object_contacts": s.object_contacts, "self_contacts": s.self_contacts,
                         "finger_friction": s.finger_friction, "reach": dataclasses.asdict(s.reach),
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
    atomically. Failed rollouts have no solution file (their frames end at the failed step). returns: the path.
    Rollouts with different objects cannot share a directory (the checker judges a result against its scene's one
    object): write each with ``result.variant_result(i)``."""
    if len({id(r.variant.object) for r in result.rollouts}) > 1:
        raise InputValueError("the rollouts have different objects: write one result directory per variant "
                              "(ResynthResult.variant_result)")
    writer = writer if writer is not None else prepare_result_dir(out, overwrite=overwrite)
    writer.begin(result, result.scene, [result.hand])
    written = []
    for i, r in enumerate(result.rollouts):
        if r.ok:
            writer.write_solution(len(written), solution_arrays(result, i), result.scene.name)
            written.append(i)
    return writer.complete(_stats(result, written))
