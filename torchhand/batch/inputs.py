"""Loading every input of a batch manifest once, before any work (:func:`torchhand.batch.manifest.load_manifest`
with ``check_inputs``): scenes, hand files, grasps and interactions, and how they fit together and with the
options. Each check raises the loader's :class:`~torchhand.errors.TorchhandError`, prefixed with the table and the
key (``[[jobs]] #2: grasps: ...``). ``seen`` caches what was loaded, so that an input listed by many jobs is read
once.
"""

from __future__ import annotations

import dataclasses

from ..errors import InputValueError, UnknownNameError

__all__ = ["check_capture", "check_manipulate", "check_synthesize", "load_scene_once"]


def load_scene_once(scene: str, where: str, seen: dict):
    """The scene, loaded once per manifest."""
    from ..errors import TorchhandError
    from ..scene import load_scene

    key = ("loaded", scene)
    if key not in seen:
        try:
            sc = load_scene(scene)
        except TorchhandError as err:
            raise type(err)(f"{where}: scenes: {scene}: {err}") from None
        seen[key] = (sc.T, tuple(sc.sides), sc)
    return seen[key][2]


def _frames(frames, sc, scene: str, where: str) -> int:
    """The number of frames the job runs (``frames`` within the scene)."""
    if frames is None:
        return sc.T
    start, stop = (int(v) for v in frames.split(":"))
    if stop > sc.T:
        raise InputValueError(f"{where}: frames: {frames!r} goes beyond scene {scene}'s {sc.T} frames")
    return stop - start


def check_synthesize(scene: str, hand: str, options: dict, where: str, seen: dict) -> None:
    """Load the scene (once) and the hand; frames within the scene; the hand's side in the scene."""
    from ..errors import TorchhandError

    sc = load_scene_once(scene, where, seen)
    sides = tuple(sc.sides)
    _frames(options.get("frames"), sc, scene, where)
    if hand != "default":
        side, _, path = hand.partition("=")
        if side not in sides:
            raise InputValueError(f"{where}: hands: scene {scene} has no {side} hand (hands: {', '.join(sides)})")
        from ..hand.mount import track_hand

        track = next(t for t in sc.hands if t.side == side)
        try:
            track_hand(dataclasses.replace(track, model=path))
        except TorchhandError as err:
            raise type(err)(f"{where}: hands: {path}: {err}") from None


def check_manipulate(scene: str, grasp: str, options: dict, where: str, seen: dict) -> None:
    """Load the scene (once) and the grasp (once) with its hand: the grasp fits its hand (joint names, limits,
    contact links), the scene has the grasp's side; frames within the scene; window within the frames."""
    from ..errors import TorchhandError
    from ..manipulation.grasp import check_grasp_hand, grasp_hand, load_grasp

    sc = load_scene_once(scene, where, seen)
    frames = _frames(options.get("frames"), sc, scene, where)
    if options["window"] > frames:
        raise InputValueError(f"{where}: window: expected at most the {frames} frames of the motion, got "
                              f"{options['window']}")
    key = ("grasp", grasp)
    if key not in seen:
        try:
            g = load_grasp(grasp)
            check_grasp_hand(g, grasp_hand(g), where=grasp)
        except TorchhandError as err:
            raise type(err)(f"{where}: grasps: {err}" if grasp in str(err) else
                            f"{where}: grasps: {grasp}: {err}") from None
        seen[key] = g
    g = seen[key]
    if g.side not in sc.sides:
        raise InputValueError(f"{where}: grasps: {grasp} is a {g.side} hand's grasp; scene {scene} has "
                              f"{', '.join(sc.sides)}")


def check_capture(scene: str, interaction: str, options: dict, where: str, seen: dict) -> None:
    """Load the scene (once; one hand), the interaction (once), the scene's hand (once): the interaction's joints
    are the hand's; the step ``dt`` (default 1 / the scene's fps) not longer than the interaction's frame time; the
    settings as ``torchhand capture resynthesize`` builds them."""
    import torch

    from ..errors import TorchhandError
    from ..interaction.grip import GripSettings
    from ..interaction.reach import ReachSettings
    from ..interaction.resynth import ResynthSettings, expand_variants, load_interaction

    sc = load_scene_once(scene, where, seen)
    if len(sc.hands) != 1:
        raise InputValueError(f"{where}: scenes: {scene}: resynthesis drives one hand, the scene has "
                              f"{len(sc.hands)}")
    o = options
    try:
        GripSettings(mode=o["grip"], ratio=o["slip_ratio"], min_force=o["min_force"], factor=o["tighten"],
                     floor=o["grip_floor"], delay=o["grip_delay"])
        ResynthSettings(dt=o["dt"], pyramid_m=o["pyramid_m"], solver=o["solver"], settle_steps=o["settle_steps"],
                        close_open=o["close_open"],
                        dtype=getattr(torch, o["dtype"]), object_contacts=o["object_contacts"],
                        sdf_voxel=o["sdf_voxel"], finger_friction=o["finger_friction"],
                        reach=ReachSettings(enabled=o["reach"], rate=o["reach_rate"], limit=o["reach_limit"]))
        expand_variants(o["mass"] or (None,), o["compliance_scale"], o["friction"] or (None,))
    except TorchhandError as err:
        raise type(err)(f"{where}: {err}") from None
    key = ("interaction", interaction)
    if key not in seen:
        try:
            seen[key] = load_interaction(interaction)
        except TorchhandError as err:
            raise type(err)(f"{where}: interactions: {err}" if interaction in str(err) else
                            f"{where}: interactions: {interaction}: {err}") from None
    inter = seen[key]
    hand_key = ("scene-hand", scene)
    if hand_key not in seen:
        from ..hand.mount import track_hand

        try:
            seen[hand_key] = tuple(track_hand(sc.hands[0]).joint_names)
        except TorchhandError as err:
            raise type(err)(f"{where}: scenes: {scene}: hand: {err}") from None
    names = seen[hand_key]
    if tuple(inter.joint_names) != names:
        missing = [n for n in inter.joint_names if n not in names]
        detail = f"joint '{missing[0]}' is not a joint of the scene's hand" if missing else \
            "the joints are the scene hand's in another order"
        raise (UnknownNameError if missing else InputValueError)(
            f"{where}: interactions: {interaction}: {detail} (scene {scene}: {len(names)} joints: "
            f"{', '.join(names[:4])}{', ...' if len(names) > 4 else ''})")
    h = o["dt"] if o["dt"] is not None else 1.0 / sc.fps
    if h > 1.0 / inter.fps + 1e-12:
        what = "dt" if o["dt"] is not None else f"1 / the fps of scene {scene}"
        raise InputValueError(f"{where}: dt: the step {h:g} s ({what}) is longer than the frame time "
                              f"{1 / inter.fps:g} s of {interaction}")
