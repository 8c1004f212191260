"""The result directory of a manipulation (:mod:`.manipulate`): the ``sol_000.npz`` arrays, stats.json and the
writer."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from .._numerics import record as numerics_record
from ._plan_records import GraspUnsuitable
from ._run_result import HandMotion, ManipulationResult


def solution_arrays(result: ManipulationResult) -> dict:
    """The ``sol_000.npz`` arrays (docs/result_format.md, docs/manipulation.md): every key of the contract plus
    ``torque`` (T, 6 + D), ``torque_names`` (6 + D,), ``torque_rest`` (6 + D,), ``contact_added`` (T, K) and the
    method's own keys (``contact_lambda``, ``planned_force``, ``contact_hand_local``, ``contact_object_local``,
    ``objective``, ``sqp_iterations``, ``mass``, ``variant_mass`` (only when ``PlanSettings.mass`` overrides the
    scene's mass), ``contact_slot`` (T, K): the contact's slot in order of creation,
    -1 where inactive (columns are sorted active-first per frame, so the slot identifies a contact across frames),
    and ``contact_slot_link`` (K,): each slot's link index, never-active slots included).

    Two hands (docs/result_format.md): per side also ``q_<side>``, ``root_pose_<side>``, ``joint_names_<side>``,
    ``guiding_<side>`` and the method's ``torque_<side>``, ``torque_rest_<side>``, ``torque_names_<side>``; ``q``,
    ``root_pose``, ``joint_names``, ``torque``, ``torque_rest`` and ``torque_names`` repeat the right hand's, and
    ``contact_link_name`` lists ``right/<link>`` and ``left/<link>`` in the hands' order."""
    from ..io.result import FORMAT_VERSION

    r = result
    T, K = r.contact_mask.shape
    order = np.argsort(~r.contact_mask, axis=1, kind="stable")          # active contacts first in every frame
    take = lambda a: np.take_along_axis(a, order[..., None] if a.ndim == 3 else order, 1)  # noqa: E731
    mask = take(r.contact_mask)
    link = np.where(mask, r.contact_link[order], -1)
    hands = r.hands or (HandMotion(r.grasp.side, r.hand, r.grasp, r.q, r.root, r.torque, r.torque_rest),)
    main = next((m for m in hands if m.side == "right"), hands[0])
    names = list(main.hand.joint_names)
    tnames = lambda jn: np.array(["root_torque_x", "root_torque_y", "root_torque_z", "root_force_x",  # noqa: E731
                                  "root_force_y", "root_force_z"] + list(jn))
    link_names = (list(main.hand.link_names) if len(hands) == 1
                  else [f"{m.side}/{n}" for m in hands for n in m.hand.link_names])
    per_side = {}
    if len(hands) > 1:
        for m in hands:
            per_side.update({f"q_{m.side}": m.q, f"root_pose_{m.side}": m.root,
                             f"joint_names_{m.side}": np.array(list(m.hand.joint_names)),
                             f"guiding_{m.side}": np.zeros((T, m.hand.num_fingers), bool),
                             f"torque_{m.side}": m.torque, f"torque_rest_{m.side}": m.torque_rest,
                             f"torque_names_{m.side}": tnames(m.hand.joint_names)})
    return {
        **per_side,
        "format_version": np.array(FORMAT_VERSION), "joint_names": np.array(names),
        "q": main.q, "root_pose": main.root, "object_pose": r.scene.object_pose.double().numpy(),
        "fps": np.array(float(r.scene.fps)),
        "contact_mask": mask, "contact_link": link.astype(np.int64), "contact_link_name": np.array(link_names),
        "contact_point": take(r.contact_point), "contact_normal": take(r.contact_normal),
        "contact_force": take(r.contact_force), "contact_sliding": take(r.contact_sliding) & mask,
        "env_contact_mask": r.env_mask, "env_contact_point": r.env_point * r.env_mask[..., None],
        "env_contact_force": r.env_force,
        "strategy": np.array("liu2009"), "friction": np.array(r.friction), "reconstructed": np.array(True),
        "guiding": np.zeros((T, main.hand.num_fingers), bool),
        "torque": main.torque, "torque_rest": main.torque_rest, "torque_equilibrium": main.torque_rest,
        "torque_names": tnames(names),
        "contact_added": take(r.contact_added) & mask, "contact_lambda": take(r.contact_lambda),
        "planned_force": take(r.planned_force), "contact_hand_local": take(r.contact_hand_local),
        "contact_object_local": take(r.contact_object_local), "objective": r.objective,
        "sqp_iterations": r.iterations, "mass": np.array(r.mass),
        "contact_slot": np.where(mask, order, -1).astype(np.int64),
        "contact_slot_link": r.contact_link.astype(np.int64),
        # a mass override (PlanSettings.mass) is not the scene's: the checker balances the solution with its own
        **({"variant_mass": np.array(float(r.mass))} if float(r.mass) != float(r.scene.object.mass) else {}),
    }


def stats_dict(result: ManipulationResult, unsuitable: GraspUnsuitable | None = None, **extra) -> dict:
    """stats.json of a manipulation result (``method: "liu2009"``). With ``unsuitable`` (the error that stopped the
    motion; ``result`` holds the frames done before it) the stats say ``complete: false``, ``status:
    "grasp_unsuitable"`` and give the frame and the wrench deficit under ``unsuitable``."""
    from ..io.result import FORMAT_VERSION

    r, s = result, result.settings
    fps_run = r.T / r.timings["total_s"] if r.timings.get("total_s") else None
    if unsuitable is not None:
        e = unsuitable
        extra = {"unsuitable": {"frame": e.frame, "window": e.window, "frames_done": r.T,
                                "deficit": e.deficit.tolist(), "deficit_force_N": float(np.linalg.norm(e.deficit[:3])),
                                "deficit_torque_Nm": float(np.linalg.norm(e.deficit[3:])),
                                "contacts": list(e.contacts), "message": str(e)}, **extra}
    return {"format_version": FORMAT_VERSION, "complete": unsuitable is None,
            "status": "complete" if unsuitable is None else "grasp_unsuitable", "method": "liu2009",
            "scene": r.scene.name,
            "T": r.T, "fps": float(r.scene.fps), "solutions": 1, "time_s": r.timings.get("total_s"),
            "frames_per_second": fps_run, "timings_s": r.timings, "added_contacts": r.num_added,
            "deferred_contacts": r.deferred,
            "max_joint_speed": s.synth.joint_speed, "sqp_iterations": r.iterations.tolist(),
            "sqp_converged": r.converged.tolist(), "frames_converged": int(np.sum(r.converged)),
            "dynamics": "full", "objective_dynamics": s.synth.dynamics, "reproject_status": r.reproject_status.tolist(),
            "settings": {"plan": dataclasses.asdict(s.plan), "synth": dataclasses.asdict(s.synth)},
            "mass": r.mass, "friction": r.friction, "threads": torch.get_num_threads(),
            "numerics": numerics_record(), **extra}


def prepare_output(out, *, overwrite: bool = False):
    """Validate and claim the result directory before any work (the synthesis writer's rules). Raises
    InputValueError with one line."""
    from ..synthesis.output import ResultWriter

    return ResultWriter(out, overwrite=overwrite)


def write_manipulation(result: ManipulationResult, out=None, *, overwrite: bool = False, writer=None,
                       unsuitable: GraspUnsuitable | None = None, **extra) -> Path:
    """Write the result directory: scene/ (with the synthesized wrist), hand.xml, solutions/sol_000.npz,
    stats.json last; every file atomically. Returns its path.

    unsuitable: the :class:`GraspUnsuitable` that stopped the motion, with ``result = unsuitable.partial`` (the
    frames done before it): the directory is a valid result of those frames whose stats.json says ``complete:
    false`` and ``status: "grasp_unsuitable"`` (:func:`stats_dict`)."""
    writer = writer if writer is not None else prepare_output(out, overwrite=overwrite)
    scene = result.scene
    motions = result.hands or (HandMotion(result.grasp.side, result.hand, result.grasp, result.q, result.root,
                                          result.torque, result.torque_rest),)
    # the written scene holds the manipulated hands, in the scene's order, with their synthesized wrists and the
    # grasps' hand models (a grasp may bring another hand file than the scene's, e.g. one on an arm)
    by_side = {h.side: h for h in scene.hands}
    tracks = [dataclasses.replace(by_side.get(m.side, scene.hands[0]), side=m.side, model=m.grasp.hand,
                                  wrist_pose=torch.as_tensor(m.root)) for m in motions]
    scene = dataclasses.replace(scene, hands=tuple(tracks))
    writer.begin(result, scene, [m.hand for m in motions])
    writer.write_solution(0, solution_arrays(result), scene.name)
    return writer.complete(stats_dict(result, unsuitable, **extra))
