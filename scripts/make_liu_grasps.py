"""Make the packaged grasps of the Liu 2009 built-in scenes: torchhand/scene/builtin/grasps/<scene>.npz.

How each grasp is made (deterministic: a seeded search on one thread, node budgets in work units):

1. ``torchhand.scene.builtin.liu.approach_scene(scene)``: the object at rest at the scene's frame-0 pose, the wrist moving
   6 cm along the palm normal onto the scene's frame-0 hand pose (the approach of the other built-in scenes),
   written as a scene directory.
2. ``torchhand synthesize`` on its first 8 frames with a small search (4 trees, 8 candidates, at most 2000 node
   tests, 1 solution, seed 0): finger motion with the fingers closing on the object (Ye & Liu 2012).
3. ``torchhand grasp from-result`` at frame ``GRASP_FRAME`` of that solution: the joint angles and the wrist in the
   object frame, snapped onto the object (links within 5 mm touch; a small finger IK closes the gaps).

Every box scene here holds the same 9 x 7 x 6 cm box from above at frame 0 (only the mass and the later motion
differ); the search's dynamic checks pass at every one of these masses, so the four box files come out
byte-identical.

``liu-roll`` (a two-finger pinch on a small cylinder) is made differently, by :func:`make_roll`: a fixed pinch
posture with the cylinder placed between the thumb's and the index's distal capsules
(:func:`torchhand.scene.builtin.liu.roll_pinch`), snapped with a 2 mm tolerance so that only the two fingertips touch.
``liu-press`` likewise, by :func:`make_press`: a fitted posture with the thumb, index and middle fingertips on the
plate's top face (:func:`torchhand.scene.builtin.liu.press_pose`), snapped with the default 5 mm tolerance.

    python scripts/make_liu_grasps.py [--only liu-drag ...] [--work DIR] [--check]
    python scripts/make_liu_grasps.py --test-grasp

``--check`` also runs ``torchhand manipulate`` and ``torchhand check`` on every scene with its new grasp.

``--test-grasp`` writes the manipulation tests' grasp instead, ``tests/data/box_turn_grasp.npz``
(:func:`make_test_grasp`): the same kind of search on box-turn's own first 8 frames, solution 0 at frame
``TEST_GRASP_FRAME`` (thumb, index and little finger on the box's sides), snapped. The tests load the file and never
search: the search's answer moves with the last bits of the arithmetic (on different CPUs its grasps differed by
about 2e-8 m, and the planner's verdicts near a mass threshold with them).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from torchhand.cli import main as cli
from torchhand.hand import default_hand
from torchhand.hand.mount import track_hand
from torchhand.manipulation import Grasp, grasp_hand, save_grasp, snap_grasp
from torchhand.manipulation.snap import SNAP_TOL
from torchhand.scene._writer import export_scene_dir
from torchhand.scene.builtin import builtin_scene
from torchhand.scene.builtin.liu import (
    _GRASPS,
    LIU_SCENES,
    SHADOW_HAND,
    TWO_HAND_SNAP_TOL,
    approach_scene,
    press_pose,
    roll_pinch,
    shadow_pose,
    two_hand_pose,
)

SYNTH = ["--frames", "0:8", "--trees", "4", "--candidates", "8", "--max-nodes", "2000", "--solutions", "1",
         "--seed", "0", "--no-progress", "--threads", "1"]
GRASP_FRAME = 7
"""Frame of the approach the grasp is taken at (the wrist 1 cm farther along the palm normal than the scene's hold
pose): thumb, index and little finger on the box's sides, seven contact links after snapping (the little-proximal
gap of 2.95 mm is the largest). At frame 6 the index-proximal link is 4.5 mm off the far face and is released after
the first frame, leaving five contacts. The frame-7 grasp holds liu-drag, liu-pivot, liu-push and a 1.5 kg lift
with its own contacts; liu-lift's 2.5 kg box makes the planner add one."""


ROLL_SNAP_TOL = 0.002
"""Snap tolerance of the liu-roll grasp, metres. The pinch leaves the thumb's proximal phalanx and the index's middle
phalanx 3.0 and 2.4 mm from the cylinder (their capsules are thicker than the distal ones they carry); with the default
5 mm they would become contacts too, and the grasp would no longer be a two-finger pinch."""


def _snap(label: str, grasp: Grasp, hand, mesh, expected: set, *, tol: float = SNAP_TOL, exact: bool = True) -> Grasp:
    """``snap_grasp`` with its report printed; stops unless the contact links are ``expected`` (``exact=False``:
    include them)."""
    snapped, report = snap_grasp(grasp, hand, mesh, tol=tol)
    for line in report.lines():
        print(f"{label} snap: {line}")
    got = set(snapped.contact_links)
    if (got != expected) if exact else not expected <= got:
        raise SystemExit(f"{label}: expected {', '.join(sorted(expected))} {'as' if exact else 'among'} the contacts, "
                         f"got {', '.join(snapped.contact_links)}")
    _GRASPS.mkdir(exist_ok=True)
    return snapped


def make_roll(work: Path | None = None) -> Path:
    """The liu-roll grasp, deterministic and without search (``work`` is not used: nothing intermediate):

    1. the pinch posture and the cylinder in the hand frame (``roll_pinch``: the thumb and the index distal capsules
       on opposite sides of the cylinder's curved surface, both roughly perpendicular to its axis, so that a rotation
       about the axis rolls the cylinder along them; the other fingers curled into the palm);
    2. ``wrist_in_object`` = the inverse of the cylinder's pose in the hand frame; frame 0 of the scene;
    3. ``snap_grasp`` with ``ROLL_SNAP_TOL``: the two distal links are the only contacts (0.2 mm gap of the index
       closed by the finger IK); the two thicker phalanges behind them are reported as gaps that are not contacts.

    How the posture was found (once; the rounded angles are in ``torchhand/scene/builtin/liu.py``): a grid over the thumb's
    six joints (6 values each) and the index's four (8 each) for distal capsules about 2 R + r_thumb + r_index apart
    and near parallel, kept when the cylinder between them cleared the other links, then a least-squares refinement
    (tangency, diametrically opposite contacts, fingertip pads facing the cylinder, about 3 mm of clearance for
    every other link and between the thumb and the index fingers), every joint kept at least 4 degrees inside its
    limits so that the fingers can move both ways.
    """
    scene = builtin_scene("liu-roll")
    hand = default_hand()
    q, T_hand_object = roll_pinch(hand)
    grasp = Grasp(hand="default", side="right", joint_names=tuple(hand.joint_names), q=q,
                  wrist_in_object=np.linalg.inv(T_hand_object), frame=0, length=0.19)
    snapped = _snap("liu-roll", grasp, grasp_hand(grasp), scene.object.mesh, {"thumb_distal", "index_distal"},
                    tol=ROLL_SNAP_TOL)
    return save_grasp(snapped, _GRASPS / "liu-roll.npz", overwrite=True)


PRESS_CONTACTS = {"thumb_distal", "index_distal", "middle_distal"}


def make_press(work: Path | None = None) -> Path:
    """The liu-press grasp, deterministic and without search (``work`` is not used):

    1. the press posture and the wrist over the plate (``press_pose``: palm down, the thumb, index and middle
       fingertips on the top face around its centre, the ring and little fingers curled above it);
    2. ``snap_grasp`` with the default 5 mm tolerance: the three distal links are the only contacts (gaps under
       1 mm, closed by the finger IK).

    How the posture was found (once; the rounded angles are in ``torchhand/scene/builtin/liu.py``): a least-squares fit of
    the wrist and the thumb, index and middle joints, starting from a flexed hand 6 cm above the plate, with each
    fingertip capsule tangent to the top face near a chosen point ((-25, 8), (15, 14), (18, -10) mm: a triangle
    around the centre, so that the fingertips can balance the spring's torque), every other link at least 4 mm from
    the plate, every joint at least 3 degrees inside its limits and a small pull toward the starting angles.
    """
    scene = builtin_scene("liu-press")
    hand = default_hand()
    q, T_object_hand = press_pose(hand)
    grasp = Grasp(hand="default", side="right", joint_names=tuple(hand.joint_names), q=q,
                  wrist_in_object=T_object_hand, frame=0, length=0.19)
    snapped = _snap("liu-press", grasp, grasp_hand(grasp), scene.object.mesh, PRESS_CONTACTS)
    return save_grasp(snapped, _GRASPS / "liu-press.npz", overwrite=True)


SHADOW_CONTACTS = {"rh_ffdistal", "rh_mfdistal", "rh_rfdistal", "rh_thdistal"}


def make_shadow_lift(work: Path | None = None) -> Path:
    """The liu-shadow-lift grasp (the Shadow hand of the shared reference data), deterministic and without search
    (``work`` is not used):

    1. the Shadow posture and the wrist on the box (``shadow_pose``: the first, middle and ring fingertips on the far
       face pointing into it, the thumb tip on the near face, the little finger curled clear of the box);
    2. ``snap_grasp`` with the default 5 mm tolerance (measured on the Shadow's own geoms' surface samples);
    3. saved with ``hand`` = ``SHADOW_HAND``, the path relative to the shared data directory
       (``torchhand.manipulation.grasp.load_packaged_grasp`` resolves it; the Shadow files are not shipped).

    How the posture was found (once; the rounded angles are in ``torchhand/scene/builtin/liu.py``): a least-squares fit of
    the wrist and every finger joint, starting from the palm 3 cm over the top face, each of the four fingertip
    capsules tangent to its face near a chosen point, the first, middle and ring distal axes within about 20 degrees
    of the face normal (the fingertip ends touch: there the fitted capsules lie within 0.6 mm of the Shadow's
    meshes, on the pads about 2 mm, more than the checker's contact tolerance), every other link at least 4 mm from
    the box and 3 mm above the table, every joint at least 3 degrees inside its limits.
    """
    scene = builtin_scene("liu-shadow-lift")            # its hand track is the Shadow hand's file
    hand = track_hand(scene.hands[0])
    q, T_object_hand = shadow_pose(hand)
    grasp = Grasp(hand=scene.hands[0].model, side="right", joint_names=tuple(hand.joint_names), q=q,
                  wrist_in_object=T_object_hand, frame=0, length=0.19)
    snapped = _snap("liu-shadow-lift", grasp, hand, scene.object.mesh, SHADOW_CONTACTS, exact=False)
    return save_grasp(dataclasses.replace(snapped, hand=SHADOW_HAND), _GRASPS / "liu-shadow-lift.npz", overwrite=True)


TWO_HAND_CONTACTS = {"thumb_metacarpal", "index_middle", "index_distal", "middle_middle", "middle_distal"}


def make_two_hand_lift(work: Path | None = None) -> Path:
    """The liu-two-hand-lift grasps (``liu-two-hand-lift.npz``, the right hand, and ``liu-two-hand-lift-left.npz``),
    deterministic and without search (``work`` is not used):

    1. each hand's flat posture and wrist on its side face (``two_hand_pose``);
    2. ``snap_grasp`` with ``TWO_HAND_SNAP_TOL``: the thumb metacarpal and the index and middle fingers' middle and
       distal links touch.

    How the posture was found (once; the rounded angles are in ``torchhand/scene/builtin/liu.py``): from the two-hand-box
    scene's hand pose (the palm centre 9 mm off the face, fingers straight), a least-squares fit of the thumb joints
    that takes the thumb 3 mm out of the face, then of the wrist and the finger joints with the palm and the four
    fingers' middle links tangent to the face and every other link at least 3 mm off it.
    """
    scene = builtin_scene("liu-two-hand-lift")
    out = None
    for track in scene.hands:
        hand = track_hand(track)
        q, T_object_hand = two_hand_pose(track.side)
        grasp = Grasp(hand="default", side=track.side, joint_names=tuple(hand.joint_names), q=q,
                      wrist_in_object=T_object_hand, frame=0, length=0.19)
        snapped = _snap(f"liu-two-hand-lift ({track.side})", grasp, hand, scene.object.mesh, TWO_HAND_CONTACTS,
                        tol=TWO_HAND_SNAP_TOL)
        name = "liu-two-hand-lift.npz" if out is None else f"liu-two-hand-lift-{track.side}.npz"
        path = save_grasp(snapped, _GRASPS / name, overwrite=True)
        out = out or path
    return out


TEST_GRASP = Path(__file__).resolve().parents[1] / "tests" / "data" / "box_turn_grasp.npz"
TEST_GRASP_FRAME = 6


def make_test_grasp(work: Path) -> Path:
    """The manipulation tests' grasp (module docstring): ``torchhand synthesize box-turn`` on frames 0-7 with the
    small search above, ``grasp_from_result`` of solution 0 at ``TEST_GRASP_FRAME``, snapped with the default 5 mm
    (``make_grasp``), written to ``TEST_GRASP``."""
    from torchhand.manipulation import grasp_from_result, make_grasp

    res = work / "box-turn-synth"
    if cli(["synthesize", "box-turn", "--out", str(res), "--overwrite"] + SYNTH) != 0:
        raise SystemExit("box-turn: synthesis failed")
    grasp, scene = grasp_from_result(res, solution=0, frame=TEST_GRASP_FRAME)
    snapped, report = make_grasp(grasp, scene)
    for line in report.lines():
        print(f"test grasp snap: {line}")
    return save_grasp(snapped, TEST_GRASP, overwrite=True)


def make(name: str, work: Path) -> Path:
    if name == "liu-two-hand-lift":
        return make_two_hand_lift(work)
    if name == "liu-shadow-lift":
        return make_shadow_lift(work)
    if name == "liu-roll":
        return make_roll(work)
    if name == "liu-press":
        return make_press(work)
    scene = builtin_scene(name)
    sdir = export_scene_dir(approach_scene(scene), work / f"{name}-approach", overwrite=True)
    res = work / f"{name}-synth"
    if cli(["synthesize", str(sdir), "--out", str(res), "--overwrite"] + SYNTH) != 0:
        raise SystemExit(f"{name}: synthesis failed")
    _GRASPS.mkdir(exist_ok=True)
    out = _GRASPS / f"{name}.npz"
    if cli(["grasp", "from-result", str(res), "--solution", "0", "--frame", str(GRASP_FRAME), "--out", str(out),
            "--overwrite"]) != 0:
        raise SystemExit(f"{name}: grasp from-result failed")
    return out


def check(name: str, grasp: Path, work: Path) -> int:
    out = work / f"{name}-manip"
    rc = cli(["manipulate", name, "--grasp", str(grasp), "--out", str(out), "--overwrite", "--threads", "1",
              "--no-progress"])
    if rc != 0:
        return rc
    return cli(["check", str(out)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=LIU_SCENES, help="these scenes only")
    ap.add_argument("--work", help="keep the intermediate scenes and results here (default: a temporary folder)")
    ap.add_argument("--check", action="store_true", help="also run manipulate and check on each scene")
    ap.add_argument("--test-grasp", action="store_true", help="write the tests' grasp (tests/data) instead")
    args = ap.parse_args(argv)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="liu-grasps-"))
    work.mkdir(parents=True, exist_ok=True)
    bad = []
    try:
        if args.test_grasp:
            print(f"box-turn: wrote {make_test_grasp(work)}")
            return 0
        for name in args.only or LIU_SCENES:
            g = make(name, work)
            print(f"{name}: wrote {g}")
            if args.check and check(name, g, work) != 0:
                bad.append(name)
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    if bad:
        print(f"failed: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
