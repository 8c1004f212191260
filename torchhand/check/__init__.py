"""Independent checks of a result directory, with exact geometry, shared by every method that writes one.

:func:`check_result` reads a result directory through :func:`torchhand.load_result` only (scene, ``hand.xml``,
``stats.json``, ``solutions/sol_*.npz``) and measures, for every frame of every solution, with NumPy, SciPy and
trimesh (no SDF grid, nothing of the method that wrote the result):

========================== ==================================================================== ===============
figure                     what                                                                 module
========================== ==================================================================== ===============
object_penetration_m       hand capsules (hand.xml) in the object mesh, trimesh signed distance :mod:`.penetration`
table_penetration_m        hand capsules under the table plane                                  :mod:`.penetration`
hand_penetration_m         capsules of one hand in the other's (two hands)                      :mod:`.penetration`
finger_penetration_m       capsules of different fingers of one hand                            :mod:`.penetration`
contact_object_m           contact point to the object surface                                  :mod:`.contacts`
contact_hand_m             contact point to its link's capsule surface                          :mod:`.contacts`
cone_violation             hand forces in the scene's friction cone about the mesh normal (the  :mod:`.contacts`
                           normal cone at edges and vertices), table forces about +z
force_error, torque_error  Newton-Euler balance, mass properties from the mesh                  :mod:`.motion`
joint_limit_rad            joints beyond hand.xml's limits                                      :mod:`.motion`
joint_speed_rad_s          finite-difference joint speed                                        :mod:`.motion`
joint_acceleration_rad_s2  finite-difference joint acceleration                                 :mod:`.motion`
distinct_deg               mean joint difference to the closest earlier solution                :mod:`.motion`
========================== ==================================================================== ===============

Each figure is the worst value over the solution and where it occurred (frame, and link, contact, joint or
solution); :data:`LIMITS` holds the acceptance limits. Conventions: metres, seconds, radians, newtons, world
frame; poses ``T_world_frame`` with column vectors; contact normals point into the object. trimesh's signed
distance is positive inside; every depth reported here is positive for penetration.

Example::

    from torchhand.check import check_result
    report = check_result("out/box-turn")
    print(report.passed, *report.failures, sep="\\n")

or ``torchhand check out/box-turn --json report.json`` (``docs/check.md``).
"""

from __future__ import annotations

from .checker import check_result, check_solution
from .report import FIGURES, LIMITS, CheckReport, Figure, SolutionCheck

__all__ = ["check_result", "check_solution", "CheckReport", "SolutionCheck", "Figure", "LIMITS", "FIGURES"]
