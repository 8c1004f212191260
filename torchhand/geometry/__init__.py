"""Geometry of rigid objects: meshes and their mass properties, signed-distance grids, rotations and pose tracks.

Modules
    ``objects``     :class:`RigidObject`, :func:`load_object` (OBJ/STL/PLY/GLB), mass properties, watertightness
    ``sdf``         :class:`SDFGrid`: signed-distance grids (negative inside), cached on disk, trilinear queries
    ``_sdf_build``  building the grids and their disk cache; ``_sdf_distance`` grid distances; ``_sdf_winding``
                    inside/outside by winding numbers (robust for open meshes); ``_sdf_common`` shared helpers
    ``euler``       Euler angles in all six orders (BVH channels)
    ``poses``       pose trajectories: interpolation, smoothing, quaternion helpers

Above :mod:`torchhand.kernels` and below the hand model, scenes and methods (docs/architecture.md).
"""
