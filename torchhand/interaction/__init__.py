"""Interaction capture (Kry & Pai 2006): capture files, contact events, joint compliance and reference trajectory.

Pipeline (pure stages over the capture's arrays; see :mod:`torchhand.interaction.pipeline`)::

    capture = load_capture("capture.npz")              # Capture: q, root_pose, fps, forces on the hand
    result = estimate_capture(capture)                 # tau = J^T f, events, compliance, theta_r
    write_interaction(result, out_dir)                 # interaction.npz, summary.json

Quasi-static resynthesis, one step of Sec. 7 (:mod:`torchhand.interaction.step`)::

    state = initial_state(hand, q, root, object_pose=E, obj=obj, env=table, settings=settings)
    state, report = quasi_static_step(state, hand, theta_r_next, root_r_next, C, obj, table, settings)

Resynthesis on a scene's object (:mod:`torchhand.interaction.resynth`, ``torchhand capture resynthesize``)::

    result = resynthesize(load_interaction("interaction.npz"), scene, variants=expand_variants(...))
    write_resynthesis(result, out_dir)

An interaction inferred from a ``torchhand synthesize`` result (:mod:`torchhand.interaction.inferred`,
``torchhand capture from-result``)::

    inf = infer_interaction("out/box-turn", solution=0, frames="12:54")
    write_inferred(inf, prepare_inferred_dir("out/inferred"))

Generalized coordinates are the 6 + D columns of ``point_jacobian(..., wrt_root=True)``: root angular (3), root
linear (3), then the joints. Units: metres, seconds, radians, newtons; compliance rad/(N m) (root linear m/N).
Format and command line: docs/interaction_capture.md.
"""

from .capture import FORMAT_VERSION, Capture, capture_hand, check_against_hand, load_capture, save_capture
from .compliance import TABLE1, default_compliance, generalized_names
from .estimate import (REASON_NAMES, ComplianceEstimate, EstimateSettings, InteractionTrajectory, Reason,
                       estimate_compliance, fit_slope, reference_trajectory)
from .events import ContactEvents, detect_contact_events
from ._contacts import BODY_OBJECT_ENV, Contacts, find_contacts, support_points
from .grip import GRIP_MODES, GripSettings, GripState, grip_update, slip_ratio
from .resynth import (Interaction, ResynthResult, ResynthSettings, Rollout, RolloutStatus, Variant, expand_variants,
                      load_interaction, object_slip, resynthesize, save_interaction, simulate, write_resynthesis)
from .step import (SOLVERS, StepObject, StepReport, StepSettings, StepState, TablePlane, displace_root,
                   initial_state, quasi_static_step, root_displacement)
from .inferred import InferredInteraction, infer_interaction, prepare_inferred_dir, write_inferred
from .pipeline import (MIN_FPS, CaptureEstimate, NoContactError, estimate_capture, generalized_coordinates,
                       joint_torques, prepare_output_dir, write_interaction)

__all__ = [
    "FORMAT_VERSION", "Capture", "capture_hand", "check_against_hand", "load_capture", "save_capture",
    "TABLE1", "default_compliance", "generalized_names",
    "REASON_NAMES", "ComplianceEstimate", "EstimateSettings", "InteractionTrajectory", "Reason",
    "estimate_compliance", "fit_slope", "reference_trajectory",
    "ContactEvents", "detect_contact_events",
    "MIN_FPS", "CaptureEstimate", "NoContactError", "estimate_capture", "generalized_coordinates", "joint_torques",
    "prepare_output_dir", "write_interaction",
    "Contacts", "find_contacts", "SOLVERS", "StepObject", "StepReport", "StepSettings", "StepState", "TablePlane",
    "displace_root", "initial_state", "quasi_static_step", "root_displacement",
    "BODY_OBJECT_ENV", "support_points", "GRIP_MODES", "GripSettings", "GripState", "grip_update", "slip_ratio",
    "Interaction", "ResynthResult", "ResynthSettings", "Rollout", "RolloutStatus", "Variant", "expand_variants",
    "load_interaction", "object_slip", "resynthesize", "save_interaction", "simulate", "write_resynthesis",
    "InferredInteraction", "infer_interaction", "prepare_inferred_dir", "write_inferred",
]
