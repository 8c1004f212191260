"""MJCF import and export of hand models (MuJoCo's XML format), without MuJoCo at run time.

Import: :func:`load_mjcf` (also ``HandModel.from_mjcf``)
    Parses the file with :mod:`xml.etree` and builds a :class:`~torchhand.hand.model.HandModel` whose forward
    kinematics equals MuJoCo's body poses (``data.xpos``, ``data.xmat``) for the same joint values.

    * ``<compiler>``: ``angle`` (MuJoCo's default is **degree**; it scales hinge/ball ranges and ``axisangle`` /
      ``euler`` angles), ``meshdir`` / ``assetdir`` (relative to the XML file), ``eulerseq``, ``autolimits``.
    * ``<default>`` classes with nesting, ``class=`` on elements and ``childclass`` on bodies and frames.
    * Orientations in every MJCF form: ``quat`` (wxyz), ``axisangle``, ``euler`` (with ``eulerseq``), ``xyaxes``,
      ``zaxis``; ``<frame>`` elements compose into their children.
    * Links: every ``<body>`` below the root, depth first (MuJoCo's body order); bodies without joints are links
      with fixed offsets. Joints, in MuJoCo's qpos order: ``hinge`` and ``slide`` map one to one (``pos`` = anchor);
      ``ball`` becomes three hinges ``<name>_x``, ``<name>_y``, ``<name>_z`` about the body axes (limits +/- the
      ball's range); a ``free`` joint is skipped on the root body and refused elsewhere. Limits: ``range`` where the
      joint is limited (``limited="true"``, or ``auto`` with a range); unlimited joints get +/- pi (hinge) or
      +/- 1 m (slide). A non-zero ``ref`` is refused (the kernels have no joint offset).
    * The root: the first body under ``<worldbody>`` (or ``root_body``). Link 0's parent frame is the FK's ``root``
      input, so the root body's own ``pos``/orientation (and its ancestors) are not part of the model: the caller
      passes the root body's world pose (MuJoCo's ``data.xpos/xmat`` of that body, before any of its own joints)
      as ``root``. A body named ``torchhand_root`` with a free joint (written by :func:`hand_to_mjcf` when the root
      link has joints of its own) is looked through.
    * Geometry: collision geoms only. A geom with ``contype="0"`` and ``conaffinity="0"`` is visual and skipped
      (meshes used only by visual geoms are not read, though their files must exist, as for MuJoCo). Capsule,
      cylinder, box, sphere (``fromto`` included) keep MJCF's size semantics; ellipsoids become meshes (a scaled
      icosphere); plane, hfield and sdf geoms and primitives fitted to meshes are refused. Mesh assets are read
      with trimesh from ``meshdir`` (or given inline by ``vertex``/``face``; a vertex list alone means its convex
      hull), scaled by ``scale``, exact duplicate vertices merged.
    * Mesh frames: MuJoCo moves a mesh's vertices into the mesh's inertial frame and moves the geom frame by the
      inverse (``model.mesh_pos``, ``model.mesh_quat``). Here the vertices stay in the mesh file's frame and the
      geom pose is the one written in the XML, so the geometry in the body frame is identical to MuJoCo's:
      ``GeomSpec.pose @ T(mesh_pos, mesh_quat) == T(model.geom_pos, model.geom_quat)``.
    * ``<include>``, ``<replicate>``, ``<attach>``, ``<composite>`` and ``<flexcomp>`` are refused with a clear
      error; tendons, equalities, actuators, sites, cameras and lights are ignored.
    * Inertials: each body's ``<inertial>`` (``pos``, orientation, ``mass``, ``diaginertia`` or ``fullinertia``)
      becomes the link's ``link_mass``, ``link_com``, ``link_inertia``; without one, and with
      ``<compiler inertiafromgeom>`` true or auto, they come from the body's geoms as MuJoCo computes them
      (``inertiagrouprange``, ``boundmass``, ``boundinertia``, ``balanceinertia``, ``settotalmass`` honoured;
      shell inertia refused). Equal to MuJoCo's ``body_mass``, ``body_ipos``, ``body_inertia`` (tests/torchhand/
      test_dynamics.py).

    Fingers (heuristic; a file written by :func:`hand_to_mjcf` stores its annotations in ``<custom>`` and those win):
    every leaf body whose chain below the nearest branching body (a body with two or more child bodies, e.g. the
    palm) carries at least two hinge joints is a finger. Its links are the bodies of that chain that have joints,
    plus the leaf when it has none, last four kept; the distal link is the leaf. All directions are taken at q = 0
    in the distal link's frame:

    * finger direction ``d``: from the nearest ancestor origin that differs from the distal link's origin to it;
    * flexion joints: the (up to three most distal) hinges of the chain whose axis is parallel (within 25 degrees)
      to the last hinge's axis, proximal first;
    * tip: the point of the distal link's collision geometry farthest along ``d`` (its support point);
    * nail normal: ``d x a`` with ``a`` the last flexion axis, signed so that it points away from the side the
      finger flexes to (positive angles flex when the joint range lies mostly above zero), orthogonal to ``d``;
    * name: the common prefix of the finger's link names without a side prefix (``rh_ff...`` -> ``ff``), else the
      leaf's name;
    * ``length``: the largest distance at q = 0 from a finger's branching body to its tip.

    ``side``: the ``side`` argument, else "right"/"left" in the file name, the model name, or the body-name prefixes
    ``rh_``/``lh_``; else "none".

Export: :func:`hand_to_mjcf` (also ``HandModel.to_mjcf``) and :func:`save_mjcf`
    A self-contained MJCF string for any hand: bodies named ``link_names``, hinge/slide joints named ``joint_names``
    with ``limited="true"`` ranges from ``joint_limits``, ``angle="radian"``, an ``<inertial>`` on every body (the
    link's mass, centre of mass and principal inertia; 1e-9 kg for massless links, which MuJoCo refuses), the root body at the identity carrying ``<freejoint name="root"/>``, so that for
    ``qpos = (root position (3), root quaternion wxyz (4), q (D))`` MuJoCo's body poses equal
    ``hand.forward_kinematics(q, root)``. (qpos[7:] follows joint_names exactly when joints are listed depth first
    along the tree, as in the default hand and every loaded hand; otherwise map through ``model.jnt_qposadr``.) When
    the root link has joints of its own (MuJoCo allows no free joint beside them), or an offset of its own (a hand
    mounted on its hand frame, :mod:`torchhand.hand.mount`), an extra top body ``torchhand_root`` carries the free
    joint and the root link sits in it at its offset (read back as that offset). A locked joint (equal limits) is
    written with a range of +/- 1e-9 around its value, since MuJoCo needs range[0] < range[1]. Geoms keep their size and pose; meshes are written inline
    (``<mesh vertex=... face=...>``): MuJoCo re-centres them as above, which leaves the world geometry unchanged
    (meshes MuJoCo cannot compile, i.e. flat or with fewer than 4 vertices, are refused). Side, length, q_rest and the
    finger annotations go into ``<custom>`` so that :func:`load_mjcf` restores them.

Modules: the reader (:mod:`~torchhand.hand._mjcf_read`, over :mod:`~torchhand.hand._mjcf_parse`,
:mod:`~torchhand.hand._mjcf_bodies` and :mod:`~torchhand.hand._mjcf_fingers`) turns a file into a plain
:class:`~torchhand.hand._specs.HandSpec`, from which :func:`~torchhand.hand.model.build_from_spec` builds the model;
the writer (:mod:`~torchhand.hand._mjcf_write`) reads a built model. Neither imports :mod:`torchhand.hand.model`.

Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

from ._mjcf_read import read_mjcf
from ._mjcf_write import hand_to_mjcf, save_mjcf
from .model import HandModel, build_from_spec

__all__ = ["load_mjcf", "hand_to_mjcf", "save_mjcf"]


def load_mjcf(path, *, root_body: str | None = None, side: str | None = None, name: str | None = None) -> HandModel:
    """Load a hand from an MJCF file (see this module's docstring for what is supported and the heuristics).

    path:      the .xml file; mesh files are found through ``<compiler meshdir/assetdir>`` relative to it
    root_body: name of the body that becomes link 0 (default: the first body under ``<worldbody>``); its world pose
               (before its own joints) is the FK's ``root`` input
    side:      "right" | "left" | "none"; default: from the file name, model name or body-name prefixes
    name:      model name; default: ``<mujoco model=...>`` or the file name
    returns: HandModel (float64, CPU); joints in MuJoCo's qpos order (free joint excluded); the model that
             :func:`~torchhand.hand.model.build_hand_model` builds from :func:`~torchhand.hand._mjcf_read.read_mjcf`'s
             spec, as ``HandModel.from_mjcf``
    raises: MissingFileError (file or mesh file missing), FileFormatError (malformed XML, unsupported or invalid
            element, naming the file and the element), UnknownNameError (``root_body`` not found)
    """
    return build_from_spec(read_mjcf(path, root_body=root_body, side=side, name=name))
