"""Biovision Hierarchy (BVH) motion files: a robust reader, an atomic writer and the Euler-angle conversions.

Format
    ``HIERARCHY`` then one or more ``ROOT name { OFFSET x y z  CHANNELS n ch1 .. chn  JOINT ... / End Site {...} }``
    blocks, then ``MOTION``, ``Frames: F``, ``Frame Time: dt`` and ``F`` lines of ``C`` numbers (C = the sum of
    all ``CHANNELS`` counts, in hierarchy order). Keywords are case-sensitive in the spec; this reader accepts any
    case and any whitespace layout (braces may share a line with other tokens).

Kinematics (what :meth:`BVHClip.global_transforms` computes)
    The local transform of a joint is ``Translate(t) @ R``, with ``R = R(ch1) @ R(ch2) @ R(ch3)`` for its rotation
    channels *in the order they are listed* (intrinsic rotations; e.g. ``Yrotation Xrotation Zrotation`` gives
    ``Ry @ Rx @ Rz``). Angles are degrees in the file and radians in every tensor this module returns. ``t`` is
    the joint's OFFSET, except that a position channel REPLACES that axis of the OFFSET (``Xposition`` sets
    ``t[0]``, and so on), for every joint, the root included. This is the usual BVH convention and Blender's
    importer's: for a root it is the "absolute root position", and the rigs whose non-root joints carry position
    channels (the CMU body in ``cmu_body_frozen_hands``, the Leap Motion exports) write those channels equal to the
    OFFSET. The rest pose (:meth:`BVHClip.rest_transforms`) has every rotation zero and every position channel at
    its OFFSET. The global transform is ``parent_global @ local``; transforms are 4x4, column-vector convention
    (``p_parent = T_parent_joint @ p_joint``), in the file's units and axes (no unit or up-axis conversion happens
    here: see :mod:`torchhand.scene.mocap`).

End Sites
    Each ``End Site`` becomes a joint without channels named ``<parent>_end`` (``is_end_site`` True), so
    fingertip positions are available from :meth:`BVHClip.global_transforms` like any other joint.
    :func:`write_bvh` writes them back as ``End Site`` blocks (their names are not written).

Tolerated quirk
    Some exporters write one more motion line than ``Frames:`` says. Exactly one extra line is dropped
    (``BVHClip.extra_lines_dropped == 1``): the FIRST line when it is all zeros (the Leap Motion gestures in
    ``leap_hand_bvh`` start with an all-zero rest row and end with real data), otherwise the LAST line;
    ``BVHClip.extra_line_dropped_at`` says which (``"first"``, ``"last"``, or None when none was dropped). Any
    other mismatch between ``Frames:`` and the number of motion lines is a
    :class:`~torchhand.errors.FileFormatError`. Blank lines are ignored everywhere.

Writing (:func:`write_bvh`)
    The clip's hierarchy (several ROOTs allowed), names, offsets, channel names and orders as they are, End Sites
    restored, ``Frames:`` equal to the number of motion lines, ``Frame Time:`` and offsets in the shortest decimal
    that reads back to the same float (at least 8 significant digits for the frame time), motion values with
    ``%.{precision}f``. One keyword per line, tab-indented, so line-based readers (Blender's) accept it. The file
    is written to a temporary file in the target folder and moved into place; on error nothing is left behind.

Euler angles
    :func:`euler_to_matrix`, :func:`matrix_to_euler` and :func:`unwrap_euler` use the BVH convention above:
    intrinsic rotations in the order of the letters, radians, for the six orders with three different axes (XYZ,
    XZY, YXZ, YZX, ZXY, ZYX). SciPy's ``Rotation.from_euler`` with the same upper-case order is the same
    rotation. Every Euler triple ``(a, b, c)`` has the twin ``(a + pi, pi - b, c + pi)`` and each angle may be
    shifted by ``2 pi``; :func:`matrix_to_euler` returns ``b`` in ``[-pi/2, pi/2]`` and ``a, c`` in ``(-pi, pi]``
    unless a ``reference`` picks the equivalent triple nearest to it.

Errors
    A missing file raises :class:`~torchhand.errors.MissingFileError`; anything malformed (missing
    ``HIERARCHY``/``MOTION``, unknown channel names, wrong channel counts, unbalanced braces, non-numeric or
    non-finite values, a frame count mismatch) raises :class:`~torchhand.errors.FileFormatError` with
    ``path:line:`` in the message. Bad input to the writer and the conversions raises a one-line
    :class:`~torchhand.errors.TorchhandError` subclass naming the argument.

Modules
    ``_bvh_clip``   :class:`BVHClip` (the record) and its kinematics
    ``_bvh_read``   :func:`read_bvh`: sections, hierarchy, motion header, motion lines
    ``_bvh_write``  :func:`write_bvh`
    the Euler-angle conversions live in :mod:`torchhand.geometry.euler` and are re-exported here
"""

from __future__ import annotations

from ..geometry.euler import _axis_rotation, euler_to_matrix, matrix_to_euler, unwrap_euler  # noqa: F401 (re-exported)
from ._bvh_clip import CHANNEL_NAMES, BVHClip
from ._bvh_read import read_bvh
from ._bvh_write import write_bvh

__all__ = ["BVHClip", "read_bvh", "write_bvh", "euler_to_matrix", "matrix_to_euler", "unwrap_euler",
           "CHANNEL_NAMES"]
