"""Manipulation from a grasping pose (Liu 2009, "Dextrous manipulation from a grasping pose").

Stages, each a function over frozen state (docs/manipulation.md):

* :mod:`.grasp`: the :class:`Grasp` input (``grasp.npz``), validated against its hand;
* :mod:`.makers`: grasps from a ``torchhand synthesize`` result or from a MuJoCo qpos vector;
* :mod:`.snap`: the initial contacts (Sec. 3 preprocessing): links within the snap tolerance, gaps closed by IK;
* :mod:`.plan`: contact-force planning (Sec. 4, Eqs. 1-4) over a sliding window with added contacts (Sec. 4.3);
  alone (:func:`plan_motion`) on the rigid-grasp assumption;
* :mod:`.synth`: per-frame hand-motion synthesis (Sec. 5, Eqs. 5-8);
* :mod:`.manipulate`: the main loop (Fig. 2) interleaving planning and synthesis, and the result directory.

Conventions (:mod:`torchhand.conventions`): metres, seconds, radians, newtons; column-vector 4x4 transforms;
contact normals point into the object; wrench = (force, torque about the object's centre of mass), world.
"""

from .grasp import LIMIT_TOL, Grasp, check_grasp_hand, grasp_hand, load_grasp, save_grasp
from .makers import grasp_from_qpos, grasp_from_result, make_grasp, read_qpos
from .plan import ForcePlan, GraspUnsuitable, PlanSettings, WindowRecord, plan_motion
from .snap import SNAP_TOL, SnapReport, snap_grasp
from .synth import SynthSettings
from .manipulate import ManipulationResult, ManipulationSettings, manipulate, write_manipulation

__all__ = ["Grasp", "load_grasp", "save_grasp", "grasp_hand", "check_grasp_hand", "LIMIT_TOL", "grasp_from_result",
           "grasp_from_qpos", "make_grasp", "read_qpos", "SnapReport", "snap_grasp", "SNAP_TOL", "PlanSettings",
           "ForcePlan", "WindowRecord", "GraspUnsuitable", "plan_motion", "SynthSettings", "ManipulationSettings",
           "ManipulationResult", "manipulate", "write_manipulation"]
