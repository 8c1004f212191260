""":func:`check_result`: every figure of every solution of a result directory, from the directory alone."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import MappingProxyType
from typing import Callable

import numpy as np

from ..errors import FileFormatError
from ..io.result import Result, Solution, load_result
from .contacts import cone_violations, contact_gaps, contact_slots
from .geometry import ObjectMesh, object_mesh
from .ground import hand_environment_depth, support_gap
from .motion import (balance_errors, joint_acceleration, joint_limit_violation, joint_speed,
                     mean_joint_difference)
from .penetration import (PosedHand, capsule_notes, finger_depth, finger_pairs, hand_hand_depth, object_depth,
                          pose_hand, table_depth)
from .report import CHECKED_FRAMES, FIGURES, CheckReport, Figure, SolutionCheck, resolve_limits
from .wrist import object_deviation, wrist_deviation

__all__ = ["check_result", "check_solution", "frame_status"]


def check_result(directory, *, limits=None, progress: Callable[[str], None] | None = None) -> CheckReport:
    """Check every frame of every solution of a result directory with exact geometry.

    Reads only the directory (:func:`torchhand.load_result`): the scene, ``hand.xml``, ``stats.json`` and the
    solution files; a partial run (``complete`` false) is checked as far as it was written. The limits are
    :data:`LIMITS` and the caller's ``limits``, nothing the result says (not ``stats.json``'s ``max_joint_speed``).

    directory: a result directory (``docs/result_format.md``)
    limits: figure name -> limit overriding :data:`LIMITS` (units of the figure's name; None for
        ``joint_acceleration_rad_s2``: twice the speed limit times fps), or None
    progress: called with one line after each solution, or None
    returns: a :class:`CheckReport`
    Raises the loader's MissingFileError / FileFormatError / ShapeError for a missing or malformed directory or
    file (naming it), UnknownNameError / InputValueError for bad ``limits``.
    """
    result = load_result(directory)
    scene = result.scene
    obj = object_mesh(scene.object.mesh, scene.object.mass)
    report_limits = resolve_limits(limits, fps=scene.fps)
    notes = []
    for side, model in result.hand_models.items():
        odd = capsule_notes(model, side)
        if odd and _has_mujoco():
            odd = [odd[0].replace("the checks use capsules fitted to it",
                                  "object and table penetration, finger-finger penetration and contact-hand "
                                  "distances are measured on its MJCF geoms posed by MuJoCo")]
        notes += odd
    if not obj.watertight:
        notes.append("the object's mesh is not watertight: mass properties from its convex hull, inside/outside "
                     "from rays both ways, the winding number where they disagree")
    checks: list[SolutionCheck] = []
    earlier: list[tuple[int, np.ndarray]] = []
    n = len(result.solution_files)
    for i in range(n):
        sol = result.solution(i)
        lim = resolve_limits(limits, fps=sol.fps)
        # rollouts of physical variants (a solution carrying its own mass: resynthesis of one interaction with other
        # masses, frictions or compliance scales) are different experiments, not alternative answers: no
        # duplicate test among them
        variant = sol.object_mass is not None
        check, q_all = check_solution(sol, result, obj, lim, [] if variant else earlier)
        checks.append(check)
        if not variant:
            earlier.append((sol.index, q_all))
        if progress is not None:
            progress(f"checked {check.name} ({i + 1}/{n}): {'ok' if check.passed else 'FAILS'}")
    return CheckReport(path=str(Path(result.path)), scene=scene.name, complete=result.complete,
                       solutions=tuple(checks), limits=MappingProxyType(report_limits), notes=tuple(notes))


def check_solution(sol: Solution, result: Result, obj: ObjectMesh, limits: dict,
                   earlier: list[tuple[int, np.ndarray]] = ()) -> tuple[SolutionCheck, np.ndarray]:
    """Every figure of one solution.

    sol: the solution; result: its directory (scene, hand models); obj: :func:`.geometry.object_mesh` of the
    scene's object; limits: :func:`.report.resolve_limits`; earlier: (index, joint angles of all hands side by
    side (T, D_all)) of the solutions before it
    returns: the :class:`SolutionCheck` and this solution's joint angles of all hands side by side
    """
    status = frame_status(sol)
    claimed = None if status is None else status != 2
    token = CHECKED_FRAMES.set(claimed)
    try:
        check, q_all = _check_frames(sol, result, obj, limits, earlier, status)
    finally:
        CHECKED_FRAMES.reset(token)
    unsolved = () if claimed is None else tuple(int(t) for t in np.nonzero(~claimed)[0])
    return dataclasses.replace(check, unsolved=unsolved), q_all


def frame_status(sol: Solution) -> np.ndarray | None:
    """The optional ``frame_status`` of the solution's file, (T,) int8 (0 solved, 1 free hand, 2 unsolved:
    docs/result_format.md), or None when the file has none (or the solution was not read from a file).
    Raises FileFormatError naming the file for a wrong shape, dtype or code."""
    path = Path(sol.path)
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        if "frame_status" not in z.files:
            return None
        st = z["frame_status"]
    if st.shape != (sol.T,) or st.dtype.kind not in "iu":
        raise FileFormatError(f"{path}: frame_status: expected shape ({sol.T},) of integers, got shape "
                              f"{tuple(st.shape)} dtype {st.dtype}")
    if not np.isin(st, (0, 1, 2)).all():
        raise FileFormatError(f"{path}: frame_status: expected codes 0, 1 or 2, got {sorted(set(st.tolist()))}")
    return st.astype(np.int8)


def _check_frames(sol: Solution, result: Result, obj: ObjectMesh, limits: dict, earlier, status):
    hands: dict[str, PosedHand] = {}
    for hs in sol.hands:
        if hs.side not in result.hand_models:
            raise FileFormatError(f"{sol.path}: has a {hs.side} hand, the scene has "
                                  f"{', '.join(result.hand_models)}")
        hands[hs.side] = pose_hand(result.hand_models[hs.side], hs.side, hs.q, hs.joint_names, hs.root_pose,
                                   sol.path)
    files = {hs.side: _hand_file(result, k, hs.side) for k, hs in enumerate(sol.hands)}
    mass, obj = _solution_mass(sol, result.scene, obj)
    fig = _penetration_figures(sol, result.scene, list(hands.values()), obj, limits, files)
    fig.update(_contact_figures(sol, result.scene, hands, obj, limits, files, mass))
    q_all, joint_figs = _motion_figures(sol, result.scene, list(hands.values()), obj, limits, earlier, mass, status)
    fig.update(joint_figs)
    ordered = MappingProxyType({n: fig[n] for n in FIGURES if n in fig})
    return SolutionCheck(index=sol.index, file=Path(sol.path).name, frames=sol.T, figures=ordered,
                         wrist=wrist_deviation(sol), object=object_deviation(sol)), q_all


def _solution_mass(sol: Solution, scene, obj: ObjectMesh) -> tuple[float, ObjectMesh]:
    """The object's mass for this solution and its mass properties: the solution's own ``variant_mass`` when the
    file holds one (rollouts of other masses in one directory), else the scene's. The inertia of a uniform body
    scales with its mass; the centre of mass does not."""
    m = sol.object_mass
    if m is None or m == scene.object.mass:
        return float(scene.object.mass), obj
    return float(m), dataclasses.replace(obj, inertia=obj.inertia * (float(m) / float(scene.object.mass)))


def _columns(arrays: list, labels: list) -> tuple[np.ndarray, list]:
    """Per-hand (T, X_h) arrays side by side, with their column labels."""
    return np.concatenate(arrays, axis=1), [x for part in labels for x in part]


def _has_mujoco() -> bool:
    import importlib.util

    return importlib.util.find_spec("mujoco") is not None


def _hand_file(result: Result, k: int, side: str) -> Path | None:
    """The result's MJCF file of its k-th hand (hand.xml, hand_<side>.xml), None when it has none."""
    scene_order = [t.side for t in result.scene.hands]
    first = scene_order[0] if scene_order else side
    f = Path(result.path) / ("hand.xml" if side == first else f"hand_{side}.xml")
    return f if f.is_file() else None


def _link_depths(sol: Solution, scene, h: PosedHand, obj: ObjectMesh, xml: Path | None):
    """(object depth, table depth or None) per link, (T, L): on the MJCF geoms posed by MuJoCo for a hand whose
    geometry is not all capsules (:mod:`.mjcf_geometry`), on the capsules otherwise."""
    env = scene.environment
    table = env.table_height if env.table else None
    if not env.plain:  # a table with an edge, a floor: the checker's own solids (.ground)
        table = env
    if xml is not None and capsule_notes(h.model, h.side):
        from .mjcf_geometry import geom_depths

        got = geom_depths(xml, h.model, h.q, sol.hand(h.side).root_pose, obj, sol.object_pose, table)
        if got is not None:
            return got
    if table is env:
        return object_depth(h, obj, sol.object_pose), hand_environment_depth(h, env)
    return object_depth(h, obj, sol.object_pose), (table_depth(h, table) if table is not None else None)


def _penetration_figures(sol: Solution, scene, hl: list[PosedHand], obj: ObjectMesh, limits: dict,
                         files: dict | None = None) -> dict:
    fig = {}
    links = [[h.link(li) for li in range(h.model.num_links)] for h in hl]
    depths = [_link_depths(sol, scene, h, obj, (files or {}).get(h.side)) for h in hl]
    values, labels = _columns([o for o, _ in depths], links)
    fig["object_penetration_m"] = Figure.worst("object_penetration_m", values, limits["object_penetration_m"],
                                               lambda t, x: labels[x])
    if scene.environment.table or scene.environment.floor:
        values, _ = _columns([tb for _, tb in depths], links)
        fig["table_penetration_m"] = Figure.worst("table_penetration_m", values, limits["table_penetration_m"],
                                                  lambda t, x: labels[x])
    if len(hl) == 2:
        h1, h2 = hl
        d = hand_hand_depth(h1, h2)
        L2 = d.shape[2]
        fig["hand_penetration_m"] = Figure.worst(
            "hand_penetration_m", d.reshape(d.shape[0], -1), limits["hand_penetration_m"],
            lambda t, x: f"{h1.link(x // L2)} - {h2.link(x % L2)}")
    pairs = [(h, finger_pairs(h.model)) for h in hl]
    values, pair_labels = _columns([_finger_depth(sol, h, p, (files or {}).get(h.side)) for h, p in pairs],
                                   [[f"{h.link(a)} - {h.link(b)}" for a, b in p] for h, p in pairs])
    fig["finger_penetration_m"] = Figure.worst("finger_penetration_m", values, limits["finger_penetration_m"],
                                               lambda t, x: pair_labels[x])
    return fig


def _finger_depth(sol: Solution, h: PosedHand, pairs: np.ndarray, xml: Path | None) -> np.ndarray:
    """Finger-finger overlap (T, Q): on the MJCF geoms by MuJoCo for a hand whose geometry is not all capsules
    (:mod:`.mjcf_geometry`), on the capsules otherwise."""
    if xml is not None and len(pairs) and capsule_notes(h.model, h.side):
        from .mjcf_geometry import geom_finger_depths

        got = geom_finger_depths(xml, h.model, h.q, sol.hand(h.side).root_pose, pairs)
        if got is not None:
            return got
    return finger_depth(h, pairs)


def _contact_figures(sol: Solution, scene, hands: dict[str, PosedHand], obj: ObjectMesh, limits: dict,
                     files: dict | None = None, mass: float | None = None) -> dict:
    first_side = next(iter(hands))
    slots = contact_slots(hands, sol.contact_link_name, sol.contact_link, sol.contact_mask, sol.path)
    gap_obj, gap_hand, closest, tri = contact_gaps(hands, slots, sol.contact_point, obj, sol.object_pose)
    t_idx, k_idx, sides, links = slots
    for side, h in hands.items():  # robot hands: the gap to the link's MJCF geoms posed by MuJoCo
        xml = (files or {}).get(side)
        sel = np.array([s == side for s in sides], dtype=bool)
        if xml is None or not sel.any() or not capsule_notes(h.model, side):
            continue
        from .mjcf_geometry import geom_contact_gaps

        got = geom_contact_gaps(xml, h.model, h.q, sol.hand(side).root_pose, t_idx[sel], links[sel],
                                sol.contact_point[t_idx[sel], k_idx[sel]])
        if got is not None:
            gap_hand[t_idx[sel], k_idx[sel]] = got

    def where(t, k):
        name = sol.contact_link_name[int(sol.contact_link[t, k])]
        return f"contact {k}, {name if '/' in name else f'{first_side}/{name}'}"

    mass = scene.object.mass if mass is None else mass
    weight = mass * max(float(np.linalg.norm(scene.gravity.numpy())), 1e-12)
    hand_cone, table_cone = cone_violations(slots, sol.contact_force, closest, tri, obj, sol.object_pose,
                                            scene.friction, sol.env_contact_mask, sol.env_contact_force,
                                            scene.environment.friction, 1e-6 * weight)
    K = hand_cone.shape[1]
    env = scene.environment
    support = {}
    if env.table or env.floor:  # every table force at a point on the surface under it
        off = np.where(sol.env_contact_mask, np.abs(support_gap(env, np.asarray(sol.env_contact_point, np.float64))),
                       np.nan)
        support["table_contact_m"] = Figure.worst("table_contact_m", off, limits["table_contact_m"],
                                                  lambda t, x: f"table contact {x}")
    return {
        "contact_object_m": Figure.worst("contact_object_m", gap_obj, limits["contact_object_m"], where),
        "contact_hand_m": Figure.worst("contact_hand_m", gap_hand, limits["contact_hand_m"], where),
        **support,
        "cone_violation": Figure.worst("cone_violation", np.concatenate([hand_cone, table_cone], axis=1),
                                       limits["cone_violation"],
                                       lambda t, x: where(t, x) if x < K else f"table contact {x - K}"),
    }


def _motion_figures(sol: Solution, scene, hl: list[PosedHand], obj: ObjectMesh, limits: dict,
                    earlier, mass: float | None = None, status: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    mass = scene.object.mass if mass is None else mass
    ext = getattr(scene, "external_wrench", None)
    f_err, t_err = balance_errors(sol, obj, mass, scene.gravity.numpy().astype(np.float64),
                                  **({"external": ext} if ext is not None else {}))
    fig = {"force_error": Figure.worst("force_error", f_err[:, None], limits["force_error"],
                                       lambda t, x: "object"),
           "torque_error": Figure.worst("torque_error", t_err[:, None], limits["torque_error"],
                                        lambda t, x: "object")}
    joints = [h.joint(j) for h in hl for j in range(h.model.num_joints)]
    q_all = np.concatenate([h.q for h in hl], axis=1)
    bounds = np.concatenate([h.model.joint_limits.numpy().astype(np.float64) for h in hl], axis=0)
    for name, values in (("joint_limit_rad", joint_limit_violation(q_all, bounds)),
                         ("joint_speed_rad_s", joint_speed(q_all, sol.fps)),
                         ("joint_acceleration_rad_s2", joint_acceleration(q_all, sol.fps))):
        fig[name] = Figure.worst(name, values, limits[name], lambda t, x: joints[x])
    # with a frame_status, distinctness is measured over the frames the method solved (its free-hand frames are
    # the same rest pose in every variant by design; its unsolved ones are not claimed)
    rows = np.ones(q_all.shape[0], dtype=bool) if status is None else status == 0
    same = [(i, mean_joint_difference(q_all[rows], q[rows])) for i, q in earlier
            if q.shape == q_all.shape and rows.any()]
    if same:
        i, d = min(same, key=lambda x: x[1])
        fig["distinct_deg"] = Figure.make("distinct_deg", d, limits["distinct_deg"], None, f"sol_{i:03d}")
    return q_all, fig
