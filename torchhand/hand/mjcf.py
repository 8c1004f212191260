"""Hand files: MJCF and URDF import through MuJoCo's compiler, MJCF export.

Import: :func:`load_mjcf` (also ``HandModel.from_file``, ``from_mjcf``, ``from_urdf``)
    MuJoCo's own compiler reads the file (:mod:`torchhand.hand._compile`; MuJoCo is a dependency): every MJCF feature
    MuJoCo reads (``<include>``, ``<default>`` classes, ``meshdir``/``assetdir``, ``<frame>``, orientations in any
    form, ``fromto``, ``<replicate>``, ...) and URDF (compiled with ``fusestatic="false"``, ``discardvisual``,
    ``balanceinertia`` and mesh paths relative to the file; see that module). What MuJoCo refuses is one line,
    MuJoCo's message included (FileFormatError; exit 2 from the CLI). The :class:`~torchhand.hand.model.HandModel`
    is built from the compiled model (:mod:`torchhand.hand._compiled_read`), so its forward kinematics equals
    MuJoCo's body poses (``data.xpos``, ``data.xmat``) for the same joint values.

    * The root: ``root_body``, else the top-level body with the most joints below it (so a scene file with a floor
      and an object loads its hand). Link 0's parent frame is the FK's ``root`` input, so the root body's own pose
      is not part of the model: the caller passes its world pose (MuJoCo's ``xpos/xmat`` of that body before its
      own joints) as ``root``. A top body ``torchhand_root`` with a free joint (torchhand's wrapper) is looked
      through.
    * Links: every body below the root, in MuJoCo's body order; bodies without joints are links with fixed offsets.
      Joints, in MuJoCo's qpos order: ``hinge`` and ``slide`` one to one (slide values and limits in metres);
      ``ball`` becomes three hinges ``<name>_x``, ``_y``, ``_z`` about the body axes (limits +/- the ball's range);
      a ``free`` joint is skipped on the root body and refused elsewhere. Limits where the joint is limited;
      unlimited joints get +/- pi (hinge) or +/- 1 m (slide). A non-zero ``ref`` is refused.
    * Geometry: collision geoms (``contype`` or ``conaffinity`` non-zero) as MuJoCo compiled them: primitives with
      MJCF's size semantics, meshes with MuJoCo's vertices (re-centred in the mesh's inertial frame, the geom pose
      moved by the inverse: the world geometry is the file's); ellipsoids become scaled icospheres; planes, height
      fields and SDF geoms are refused.
    * Inertials: MuJoCo's (``body_mass``, ``body_ipos``, ``body_iquat``, ``body_inertia``), whatever the file's way
      of giving them (explicit, from geoms, ``settotalmass``, ``balanceinertia``).
    * Couplings: fixed tendons over the hand's joints and joint equality constraints are reported
      (``HandModel.couplings``, ``torchhand hand show``); the kinematics keep every joint free.

    Fingers, thumb, palm and side by topology (:mod:`torchhand.hand._topology`; names are never required): the
    palm is the first body where three or more jointed chains branch, each chain is a finger, the thumb is the
    finger whose flexion axis opposes the others', the side follows from the thumb's position. A file written by
    :func:`hand_to_mjcf` stores its annotations in ``<custom>`` and those win.

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

Modules: the reader (:mod:`~torchhand.hand._read`, over :mod:`~torchhand.hand._compile`,
:mod:`~torchhand.hand._compiled_read` and :mod:`~torchhand.hand._topology`) turns a file into a plain
:class:`~torchhand.hand._specs.HandSpec`, from which :func:`~torchhand.hand.model.build_from_spec` builds the model;
the writer (:mod:`~torchhand.hand._mjcf_write`) reads a built model. Neither imports :mod:`torchhand.hand.model`.

Conventions: metres, radians, quaternions wxyz, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

from ._read import read_hand_file
from ._mjcf_write import hand_to_mjcf, save_mjcf
from .model import HandModel, build_from_spec

__all__ = ["load_mjcf", "hand_to_mjcf", "save_mjcf"]


def load_mjcf(path, *, root_body: str | None = None, side: str | None = None, name: str | None = None) -> HandModel:
    """Load a hand from an MJCF or URDF file (see this module's docstring for what is read and the rules).

    path:      the .xml or .urdf file (MuJoCo resolves includes and mesh files)
    root_body: name of the body that becomes link 0 (default: the top-level body with the most joints below it);
               its world pose (before its own joints) is the FK's ``root`` input
    side:      "right" | "left" | "none"; default: the stored annotation, else the thumb's side
    name:      model name; default: ``<mujoco model=...>`` or the file name
    returns: HandModel (float64, CPU); joints in MuJoCo's qpos order (free joint excluded); the model that
             :func:`~torchhand.hand.model.build_hand_model` builds from
             :func:`~torchhand.hand._read.read_hand_file`'s spec, as ``HandModel.from_file``
    raises: MissingFileError (file missing), FileFormatError (what MuJoCo refuses, or an unsupported element, on
            one line), UnknownNameError (``root_body`` not found)
    """
    return build_from_spec(read_hand_file(path, root_body=root_body, side=side, name=name))
