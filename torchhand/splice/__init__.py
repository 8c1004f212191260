"""Hand/body splicing (Majkowska, Zordan & Faloutsos 2006): a separately captured hand carried onto a body capture.

Steps, one module each (docs/splice.md):

* :mod:`torchhand.splice.rigs`: which joint is which (arms; fingers by (finger, phalanx ordinal)) in any BVH rig;
* :mod:`torchhand.splice.markers`: the paper's four markers per arm by forward kinematics, units and axes;
* :mod:`torchhand.splice.align`: the two-pass DTW (Eqs. 6-9 in ``torchhand.kernels.splice_cost``), B pairs at once;
* :mod:`torchhand.splice.retime`: BVH motion at fractional frames (slerp);
* :mod:`torchhand.splice.retarget`: finger rotations from a hand rig onto a body rig, finger joints for a body
  without any;
* :mod:`torchhand.splice.splice`: the whole splice of two clips; :mod:`torchhand.splice.output`: its files;
* :mod:`torchhand.splice.synthetic`: hand sessions with a known time warp made from real body capture.
"""

from .align import Alignment, SpliceSettings, align
from .markers import ArmJoints, Markers, virtual_markers
from .output import prepare_out, write_splice
from .retarget import (FOREARM_LENGTH, HAND_LENGTH, Inserted, Match, Retargeted, finger_matches, hand_frame,
                       insert_fingers, retarget_fingers)
from .rigs import FINGERS, KNOWN_RIGS, Arm, Rig, detect_rig, rest_positions
from .splice import ClipAxes, SpliceResult, splice

__all__ = ["FINGERS", "KNOWN_RIGS", "Arm", "Rig", "detect_rig", "rest_positions", "Match", "Retargeted",
           "Inserted", "HAND_LENGTH", "FOREARM_LENGTH", "hand_frame", "finger_matches", "retarget_fingers",
           "insert_fingers", "SpliceSettings", "Alignment", "align", "ArmJoints", "Markers", "virtual_markers",
           "ClipAxes", "SpliceResult", "splice", "prepare_out", "write_splice"]
