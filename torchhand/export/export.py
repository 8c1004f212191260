"""Export a result directory (docs/result_format.md): the one entry point behind ``torchhand export``.

Written against the result contract only (``load_result``), so every method that writes a result directory gets
the same export. Files in ``DIR`` (docs/export.md):

    sol_XXX.bvh            the first hand of solution XXX (XXX from ``solutions/sol_XXX.npz``)
    sol_XXX_<side>.bvh     the second hand, for two-hand results
    sol_XXX.glb            the whole solution as glTF 2.0: object, table, hands, optional contacts
    sol_XXX.fbx            the whole solution as FBX (through Blender): hand armatures, object mesh
    body_with_fingers.bvh  with ``onto``: the captured body with the solution's fingers (one solution);
                           body_with_fingers_XXX.bvh per solution when several are asked for; also as
                           .fbx with the fbx format
    export.json            what was written, with the settings and the onto report

Every file is written atomically. ``DIR`` is checked before any work: a new or empty directory, or an earlier
export (``export.json``) replaced only with ``overwrite``; files of that earlier export that are not written again
are then removed, and the report lists them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from .._atomic import atomic_json, writable_dir
from ..scene.bvh import read_bvh, write_bvh
from ..errors import InputValueError
from ..io.result import load_result, parse_solution_spec
from .fbx import body_fbx_scene, find_blender, solution_fbx_scene, write_fbx
from .skeleton import UNITS, UP_AXES, hand_motion_clip, hand_skeleton

__all__ = ["FORMATS", "DEFAULT_FORMATS", "ExportReport", "export_result", "prepare_export_dir"]

FORMATS = ("bvh", "gltf", "fbx")
DEFAULT_FORMATS = ("bvh", "gltf")
_REPORT = "export.json"


@dataclass(frozen=True)
class ExportReport:
    """What an export wrote.

    out: the directory; files: the files written, in order (paths); removed: files of an earlier export removed
    report: the JSON object written to ``export.json``
    """

    out: Path
    files: tuple
    removed: tuple = ()
    report: dict = field(default_factory=dict)


def prepare_export_dir(out, *, overwrite: bool = False) -> tuple[Path, list[str]]:
    """Check (and create) ``out`` before any work; returns it and the files of an earlier export there."""
    import json

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputValueError(f"--out {out}: exists and is not a directory")
    earlier: list[str] = []
    if out.is_dir() and any(out.iterdir()):
        if not (out / _REPORT).is_file():
            raise InputValueError(f"--out {out}: exists, is not empty and holds no earlier export ({_REPORT}); "
                                  "choose a new directory (nothing was written)")
        if not overwrite:
            raise InputValueError(f"--out {out}: holds an earlier export; pass --overwrite to replace it or choose "
                                  "another directory")
        try:
            earlier = [str(f) for f in json.loads((out / _REPORT).read_text()).get("files", [])]
        except (OSError, ValueError, AttributeError):
            earlier = []
    return writable_dir(out), earlier


def export_result(result_dir, out, *, solutions: str | None = "all", formats=DEFAULT_FORMATS, units: str = "cm",
                  up: str = "y", contacts: bool = False, onto=None, blend: float = 0.2, body_rig: str = "auto",
                  overwrite: bool = False, progress=None) -> ExportReport:
    """Export solutions of the result directory ``result_dir`` into ``out`` (module docstring).

    Args:
        result_dir: a result directory (``torchhand synthesize`` or any method writing the same format)
        out: the output directory
        solutions: "all", "0,2", "1:4" or None (solution 0); with ``onto``, None means solution 0
        formats: any of "bvh", "gltf", "fbx" (an empty tuple with ``onto``: only the body); "fbx" runs Blender
            (:func:`torchhand.export.fbx.find_blender`), found before any work
        units: BVH units, "cm" (default) or "m"; up: BVH up axis, "y" (default) or "z"; glTF is always metres, y-up
        contacts: also put contact points as small spheres into the glb
        onto: path of the body BVH the scene was imported from: also write ``body_with_fingers.bvh``
        blend: seconds of blend at the segment's inner ends for ``onto``
        body_rig: the body's rig for ``onto``: "auto", a rig name or a TOML map
        overwrite: replace an earlier export in ``out``
        progress: optional callable(str)

    Raises:
        InputValueError and the other :class:`~torchhand.errors.TorchhandError` subclasses, with nothing written
        when the arguments, the result or ``out`` are wrong.
    """
    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    formats = _check_options(tuple(formats), units, up, onto)
    result_dir = Path(result_dir)
    if (result_dir / "spliced.bvh").is_file() and not (result_dir / "solutions").exists():
        raise InputValueError(f"{result_dir}: is a splice output; its spliced.bvh is already a BVH of the body "
                              "with fingers (open it directly)")
    result = load_result(result_dir)
    if not result.complete:
        say(f"{result_dir} is a partial run (stats.json: complete false): exporting the "
            f"{len(result.solution_files)} solution(s) written so far")
    indices = parse_solution_spec(solutions, len(result.solution_files))
    body = read_bvh(onto) if onto is not None else None
    if body is not None and result.scene.source is None:
        raise InputValueError(f"--onto: the scene of {result_dir} was not imported from motion capture (its "
                              "scene.toml has no [source] table); only `scene import-mocap --body-bvh` scenes can "
                              "be written back onto their body")
    blender = find_blender() if "fbx" in formats else None        # found, or missing, before anything is written
    out, earlier = prepare_export_dir(out, overwrite=overwrite)
    written: list[Path] = []
    per_solution = []
    skeletons = {side: hand_skeleton(m) for side, m in result.hand_models.items()}
    if "gltf" in formats:
        from .gltf import write_solution_glb
    for n, i in enumerate(indices):
        sol = result.solution(i)
        name = f"sol_{sol.index:03d}" if sol.index >= 0 else f"sol_{i:03d}"
        say(f"solution {n + 1}/{len(indices)}: {name}")
        files = []
        if "bvh" in formats:
            for k, hand in enumerate(sol.hands):
                path = out / (f"{name}.bvh" if k == 0 else f"{name}_{hand.side}.bvh")
                model = result.hand_models[hand.side]
                clip = hand_motion_clip(model, skeletons[hand.side], hand.q, hand.root_pose, sol.fps, units=units,
                                        up=up, path=str(path))
                write_bvh(clip, path, precision=8 if units == "m" else 6)
                files.append(path)
        if "gltf" in formats:
            path = out / f"{name}.glb"
            write_solution_glb(result, i, path, contacts=contacts)
            files.append(path)
        if "fbx" in formats:
            files.append(write_fbx(solution_fbx_scene(result, i), out / f"{name}.fbx", blender=blender))
        entry = {"solution": name, "files": [f.name for f in files]}
        if body is not None:
            from .onto import fingers_onto_body

            bpath = out / ("body_with_fingers.bvh" if len(indices) == 1 else f"body_with_fingers_{name[4:]}.bvh")
            done = fingers_onto_body(result, i, body, blend=blend, body_rig=body_rig, progress=say)
            body_files = [write_bvh(done.clip, bpath, precision=_decimals(onto))]
            if "fbx" in formats:
                body_files.append(write_fbx(body_fbx_scene(done.clip, result.scene.source),
                                            bpath.with_suffix(".fbx"), blender=blender))
            files += body_files
            entry["files"] += [f.name for f in body_files]
            entry["onto"] = done.report
        written += files
        per_solution.append(entry)
    names = {f.name for f in written}
    removed = []
    for old in earlier:
        p = out / Path(old).name
        if p.name not in names and p.is_file() and p.suffix in (".bvh", ".glb", ".fbx"):
            p.unlink()
            removed.append(p.name)
    report = {
        "result": str(result_dir), "result_complete": bool(result.complete), "solutions": per_solution, "files": sorted(names),
        "formats": list(formats), "bvh_units": units, "bvh_up": up, "contacts": bool(contacts),
        "onto": str(onto) if onto is not None else None, "blend_s": float(blend) if onto is not None else None,
        "fbx_blender": None if blender is None else blender.source,
        "removed_from_earlier_export": removed, "seconds": time.perf_counter() - t0,
    }
    atomic_json(out / _REPORT, report)
    return ExportReport(out=out, files=tuple(written), removed=tuple(removed), report=report)


def _check_options(formats: tuple, units: str, up: str, onto) -> tuple:
    """The formats, after checking them, the BVH units and axes (one-line InputValueErrors)."""
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise InputValueError(f"--format: unknown format(s) {', '.join(bad)}; expected bvh, gltf, fbx")
    if units not in UNITS:
        raise InputValueError(f"--units: expected m or cm, got {units!r}")
    if up not in UP_AXES:
        raise InputValueError(f"--up: expected y or z, got {up!r}")
    if not formats and onto is None:
        raise InputValueError("--format: nothing to write (give bvh, gltf, fbx or --onto)")
    return formats


def _decimals(path) -> int:
    """Decimals of the motion values of a BVH file (at least 6, at most 17), so that a rewrite keeps its values."""
    best = 6
    with open(path, encoding="utf-8", errors="replace") as fh:
        in_motion = False
        for line in fh:
            if not in_motion:
                in_motion = line.strip().upper().startswith("MOTION")
                continue
            if line.lstrip().startswith(("Frames", "Frame Time")):
                continue
            for tok in line.split():
                if "." in tok and "e" not in tok.lower():
                    best = max(best, len(tok) - tok.index(".") - 1)
    return min(best, 17)
