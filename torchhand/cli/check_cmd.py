"""``torchhand check RESULT_DIR [--json FILE] [--limit NAME=VALUE ...]``: independent checks of a result directory,
with exact geometry.

Every frame of every solution: hand-object, hand-table, hand-hand and finger-finger penetration of hand.xml's
capsules; contact points on the object and on their links; every force in its friction cone (the scene's friction,
the mesh's normals); the object's Newton-Euler balance with mass properties from its mesh; joint limits, speeds
and accelerations; duplicate solutions (torchhand.check, docs/check.md).

The limits are the checker's own (torchhand.check.LIMITS), whatever the result says about itself (stats.json's
max_joint_speed is information only); --limit NAME=VALUE replaces one, in the units of its name, e.g.
--limit joint_speed_rad_s=12 (rad/s); `default` restores LIMITS' value (joint_acceleration_rad_s2: twice the speed
limit times fps). The table's limit row and the JSON report's "limits" show the limits in force.

Prints one row per solution with its worst figures (a * marks a failing one), a verdict line, and one line per
failing solution naming its failing figures. Exit code 0 when every solution passes, 1 when any fails (or there
is none), 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

from ..errors import InputValueError, MissingFileError, UnknownNameError
from ._common import add_threads_argument, apply_threads

_COLUMNS = (  # figure, header, scale, format
    ("object_penetration_m", "obj mm", 1e3, "{:.1f}"),
    ("table_penetration_m", "table mm", 1e3, "{:.1f}"),
    ("hand_penetration_m", "hands mm", 1e3, "{:.1f}"),
    ("finger_penetration_m", "fingers mm", 1e3, "{:.1f}"),
    ("contact_object_m", "c-obj mm", 1e3, "{:.1f}"),
    ("contact_hand_m", "c-hand mm", 1e3, "{:.1f}"),
    ("cone_violation", "cone", 1.0, "{:.1e}"),
    ("force_error", "force", 1.0, "{:.3f}"),
    ("torque_error", "torque", 1.0, "{:.3f}"),
    ("joint_limit_rad", "limit rad", 1.0, "{:.1e}"),
    ("joint_speed_rad_s", "rad/s", 1.0, "{:.1f}"),
    ("joint_acceleration_rad_s2", "rad/s2", 1.0, "{:.0f}"),
    ("distinct_deg", "diff deg", 1.0, "{:.1f}"),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="independent physical checks of a result directory (exact geometry)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", metavar="RESULT_DIR", help="a result directory (e.g. of `torchhand synthesize`)")
    p.add_argument("--json", metavar="FILE", help="also write the whole report as JSON (atomically)")
    p.add_argument("--limit", action="append", default=[], metavar="NAME=VALUE",
                   help="replace the checker's limit of figure NAME (torchhand.check.LIMITS) by VALUE, a number >= 0 "
                        "in the units of the name, or `default`; repeatable (the last of one name counts)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from torchhand.check import check_result

    limits = parse_limits(args.limit)
    json_path = None
    if args.json:
        json_path = Path(args.json)
        folder = json_path.parent if str(json_path.parent) else Path(".")
        if not folder.is_dir():
            raise MissingFileError(f"--json: folder {folder} does not exist")
    progress = None if args.no_progress else (lambda line: print(line, file=sys.stderr, flush=True))
    report = check_result(args.result, limits=limits, progress=progress)
    if json_path is not None:
        _write_json(json_path, report.to_dict())
    print(format_table(report))
    n, ok = len(report.solutions), sum(s.passed for s in report.solutions)
    run_kind = "complete run" if report.complete else "partial run"
    if n == 0:
        print(f"FAIL: {report.path} has no solutions to check ({run_kind})")
        return 1
    verdict = "PASS" if report.passed else "FAIL"
    flagged = sum(len(s.unsolved) for s in report.solutions)
    claimed = "" if not flagged else (f" on the frames they claim; {flagged} of "
                                      f"{sum(s.frames for s in report.solutions)} frames flagged unsolved, not checked")
    print(f"{verdict}: {ok} of {n} solutions pass ({run_kind}, scene {report.scene}){claimed}")
    for note in report.notes:
        print(f"note: {note}")
    for s in report.solutions:
        if s.unsolved:
            print(f"note: {s.name}: {len(s.unsolved)} of {s.frames} frames flagged unsolved by the method "
                  f"(frame_status 2: not claimed, not checked): {_ranges(s.unsolved)}")
        for side, d in s.wrist.items():
            print(f"note: {s.name} {side} wrist moved from the capture by median {d['median_translation_mm']:.2f} mm "
                  f"/ {d['median_rotation_deg']:.2f} deg, at most {d['max_translation_mm']:.2f} mm / "
                  f"{d['max_rotation_deg']:.2f} deg ({d['frames_moved']} frames; per frame in --json)")
        if s.object:
            d = s.object
            print(f"note: {s.name} object moved from the capture by median {d['median_translation_mm']:.2f} mm / "
                  f"{d['median_rotation_deg']:.2f} deg, at most {d['max_translation_mm']:.2f} mm / "
                  f"{d['max_rotation_deg']:.2f} deg ({d['frames_moved']} frames; per frame in --json)")
    for line in report.failures:
        print(line)
    if json_path is not None:
        print(f"wrote {json_path}")
    return 0 if report.passed else 1


def _ranges(frames) -> str:
    """Frame numbers as ranges: "3-7, 12"."""
    out, start = [], None
    for i, t in enumerate(frames):
        if start is None:
            start = t
        if i + 1 == len(frames) or frames[i + 1] != t + 1:
            out.append(f"{start}-{t}" if t > start else f"{start}")
            start = None
    return ", ".join(out)


def parse_limits(items) -> dict:
    """``--limit`` values (``NAME=VALUE`` strings) as a ``check_result`` limits mapping: figure name -> float, or
    -> :data:`~torchhand.check.LIMITS`' value for ``default`` (None for ``joint_acceleration_rad_s2``).

    Raises InputValueError for a missing ``=``, a value that is not a finite number >= 0 nor ``default``, and
    UnknownNameError for a name that is not a figure of LIMITS.
    """
    from torchhand.check import LIMITS

    out: dict = {}
    for item in items:
        name, eq, text = item.partition("=")
        name, text = name.strip(), text.strip()
        if not eq or not name:
            raise InputValueError(f"--limit: expected NAME=VALUE, got {item!r}")
        if name not in LIMITS:
            raise UnknownNameError(f"--limit: unknown figure {name!r}; known: {', '.join(LIMITS)}")
        if text.lower() == "default":
            out[name] = LIMITS[name]
            continue
        try:
            value = float(text)
        except ValueError:
            raise InputValueError(f"--limit {name}: expected a number >= 0 or 'default', got {text!r}") from None
        if not math.isfinite(value) or value < 0:
            raise InputValueError(f"--limit {name}: expected a finite number >= 0, got {text!r}")
        out[name] = value
    return out


def format_table(report) -> str:
    """One row per solution: its worst figures, a * after a failing one, "-" where a figure does not apply."""
    present = [c for c in _COLUMNS if any(c[0] in s.figures for s in report.solutions)]
    header = ["solution", "ok"] + [c[1] for c in present]
    rows = [header]
    for s in report.solutions:
        row = [s.name, "yes" if s.passed else "NO"]
        for name, _, scale, fmt in present:
            f = s.figures.get(name)
            row.append("-" if f is None else fmt.format(f.value * scale) + ("" if f.ok else "*"))
        rows.append(row)
    limit_row = ["limit", ""] + [fmt.format(report.limits[name] * scale) if name in report.limits else ""
                                 for name, _, scale, fmt in present]
    rows.append(limit_row)
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    return "\n".join("  ".join(c.rjust(w) if i > 1 else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths)))
                     for r in rows)


def _write_json(path: Path, data: dict) -> None:
    folder = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=2)
            fh.write("\n")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
