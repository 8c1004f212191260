"""Hand models: the typed :class:`HandModel`, the default 36-DOF human hand, MJCF import and export."""

from .default import FINGER_NAMES, default_hand
from .model import FingerSpec, GeomSpec, HandModel, InertialSpec, JointSpec, LinkGeoms, LinkSpec, build_hand_model

__all__ = ["HandModel", "default_hand", "build_hand_model", "LinkSpec", "JointSpec", "GeomSpec", "FingerSpec",
           "LinkGeoms", "InertialSpec", "FINGER_NAMES"]
