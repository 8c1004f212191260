"""Default joint compliances from Kry & Pai (2006), Table 1, extended to every degree of freedom of a hand.

Table 1 (rad/(N m), exploring / scratching; "<" marks upper bounds, used as values here):
wrist 0.3488 / 0.1531; MP 0.9882 / 0.4788; PIP 0.6715 / < 0.8426; DIP 2.0052 / < 0.8432.

Generalized coordinates (6 + D): root angular (3, the wrist rotation; rad/(N m)), root linear (3, m/N), then the D
joints in ``joint_names`` order (the ``point_jacobian(..., wrt_root=True)`` column order).

Assignment (the paper measured one index finger; everything beyond it is an assumption, flagged as such):

* root angular: the wrist value; root linear: :data:`ROOT_LINEAR` m/N per axis (no value in the paper);
* a joint whose name contains "wrist": the wrist value;
* each finger's annotated flexion joints (``HandModel.flexion_joints``, proximal first; for the thumb of the
  default hand CMC flexion, MCP flexion, IP): MP, PIP, DIP;
* other joints with "abd" in their name (abduction): 0.5 x MP; any other joint (palm CMC, roll): 0.1 x MP.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputValueError

__all__ = ["TABLE1", "ROOT_LINEAR", "PRESETS", "default_compliance", "generalized_names"]

TABLE1 = {
    "exploring": {"wrist": 0.3488, "mp": 0.9882, "pip": 0.6715, "dip": 2.0052},
    "scratching": {"wrist": 0.1531, "mp": 0.4788, "pip": 0.8426, "dip": 0.8432},
}
"""Kry & Pai (2006) Table 1, rad/(N m)."""

ROOT_LINEAR = 1e-4
"""m/N per axis: root translation compliance (not given by the paper)."""

PRESETS = tuple(f"table1-{task}" for task in TABLE1)

ROOT_NAMES = ("root_rx", "root_ry", "root_rz", "root_x", "root_y", "root_z")


def generalized_names(joint_names) -> tuple:
    """Names of the 6 + D generalized coordinates: ``root_rx .. root_z`` then the joint names."""
    return ROOT_NAMES + tuple(joint_names)


def default_compliance(hand, preset: str = "table1-exploring"):
    """Compliance of every generalized coordinate from a Table 1 preset.

    hand:   HandModel (joint names and ``flexion_joints`` are read)
    preset: "table1-exploring" or "table1-scratching"
    returns: (values (6 + D,) rad/(N m) (root linear m/N), source (6 + D,) tuple of str naming the rule used:
        "table1:wrist", "table1:mp", "table1:pip", "table1:dip" (measured by the paper) or "assumed:..." (not))
    """
    if preset not in PRESETS:
        raise InputValueError(f"--default-compliance: expected one of {', '.join(PRESETS)}, got {preset!r}")
    table = TABLE1[preset.split("-", 1)[1]]
    D = hand.num_joints
    values = np.empty(6 + D)
    source = ["assumed:wrist"] * 3 + ["assumed:root-linear"] * 3
    values[:3], values[3:6] = table["wrist"], ROOT_LINEAR
    role = {}
    for row in hand.flexion_joints.tolist():
        for k, j in enumerate(row):
            if j >= 0:
                role[int(j)] = ("mp", "pip", "dip")[k]
    for j, name in enumerate(hand.joint_names):
        low = name.lower()
        if "wrist" in low:
            values[6 + j], s = table["wrist"], "table1:wrist"
        elif j in role:
            values[6 + j], s = table[role[j]], f"table1:{role[j]}"
        elif "abd" in low:
            values[6 + j], s = 0.5 * table["mp"], "assumed:0.5*mp"
        else:
            values[6 + j], s = 0.1 * table["mp"], "assumed:0.1*mp"
        source.append(s)
    return values, tuple(source)
