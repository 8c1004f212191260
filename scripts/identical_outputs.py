"""Run the outputs a change must keep byte-identical, and compare two such runs.

    python scripts/identical_outputs.py run OUT [--only REGEX]   # every job into OUT/<job>/, digests in OUT/digests.json
    python scripts/identical_outputs.py compare A/digests.json B/digests.json
    python scripts/identical_outputs.py rehash OUT               # digests again from OUT's files

The jobs (each a ``torchhand`` command or a script, run as a user would, under the portable numeric profile):

    synth-SCENE       ``torchhand synthesize SCENE --seed 0`` with the README's budget, every built-in synthesis scene
    manip-SCENE       ``torchhand manipulate SCENE``, the eight built-in Liu (2009) examples
    capture-*         ``torchhand capture synthetic | estimate | from-result | resynthesize``, and the two demos
                      (scripts/demo_resynth.py, scripts/demo_inferred.py on synth-box-turn's result)
    splice-*          ``torchhand splice`` on the shared CMU body with a Leap hand clip, and
                      scripts/splice_accuracy.py on one body, level and seed (needs ../shared/data)

What is compared: every file each job writes. ``.npz`` files by their arrays (name, dtype, shape, bytes; not the
zip container's write times); ``.json`` files with wall-clock figures and the machine description removed (keys
ending in ``_s`` or ``_ms``, ``seconds``, ``time``/``timings``, ``per_second``, ``numerics``, ``machine``, ``host``, ``date``); other files by
their bytes, with the output directory's path replaced by ``<OUT>`` and the run's by ``<RUN>`` (also in text
arrays of ``.npz`` files); a job's printed lines likewise, with wall-clock
figures (``in 2.8 s``, ``17.0 frames/s``) masked.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TORCHHAND_SHARED_DATA", ROOT.parent / "shared" / "data")).resolve()
SYNTH_SCENES = ["box-turn", "box-pickup", "bottle-turn", "mug-pickup", "two-hand-box", "cube-turn"]
MANIP_SCENES = ["liu-drag", "liu-lift", "liu-pivot", "liu-push", "liu-roll", "liu-press", "liu-shadow-lift",
                "liu-two-hand-lift"]
VOLATILE_KEY = re.compile(r"(_s$|^s$|_ms$|seconds|time|per_second|numerics|machine|host|date|created|elapsed|wall)", re.I)
VOLATILE_TEXT = [
    (re.compile(r"\d+(\.\d+)?(e[-+]?\d+)? ?(s|ms|min|frames/s|nodes/s|steps/s|it/s|/s)\b"), "<T>"),
    (re.compile(r"\d+:\d\d(:\d\d)?"), "<CLOCK>"),
]


def jobs(out: Path) -> list[tuple[str, list[str]]]:
    th = [sys.executable, "-m", "torchhand.cli"]
    py = [sys.executable]
    j: list[tuple[str, list[str]]] = []
    for s in SYNTH_SCENES:
        j.append((f"synth-{s}", th + ["synthesize", s, "--seed", "0", "--out", "{dir}", "--no-progress"]))
    for s in MANIP_SCENES:
        j.append((f"manip-{s}", th + ["manipulate", s, "--out", "{dir}", "--no-progress"]))
    j += [
        ("capture-synthetic", th + ["capture", "synthetic", "--out", "{dir}"]),
        ("capture-estimate", th + ["capture", "estimate", str(out / "capture-synthetic" / "capture.npz"),
                                   "--out", "{dir}"]),
        ("capture-from-result", th + ["capture", "from-result", str(out / "synth-box-turn"), "--out", "{dir}",
                                      "--frames", "12:54"]),
        ("capture-resynthesize", th + ["capture", "resynthesize",
                                       str(out / "capture-from-result" / "interaction.npz"),
                                       "--scene", "box-turn", "--out", "{dir}"]),
        ("capture-demo-resynth", py + [str(ROOT / "scripts" / "demo_resynth.py"), "--out", "{dir}"]),
        ("capture-demo-inferred", py + [str(ROOT / "scripts" / "demo_inferred.py"), "--out", "{dir}",
                                        "--result", str(out / "synth-box-turn"), "--frames", "12:54"]),
    ]
    mocap = SHARED / "mocap"
    if mocap.is_dir():
        j += [
            ("splice-cmu-leap", th + ["splice", "--body", str(mocap / "cmu_body_frozen_hands" / "01-01_v01.bvh"),
                                      "--hand", str(mocap / "leap_hand_bvh" / "gesture-pointing.bvh"),
                                      "--out", "{dir}", "--no-progress"]),
            ("splice-accuracy", py + [str(ROOT / "scripts" / "splice_accuracy.py"), "--bodies", "mocapbank",
                                      "--levels", "L4", "--seeds", "0", "--json", "{dir}/accuracy.json"]),
        ]
    return j


def _clean_json(x):
    if isinstance(x, dict):
        return {k: _clean_json(v) for k, v in x.items() if not VOLATILE_KEY.search(str(k))}
    if isinstance(x, list):
        return [_clean_json(v) for v in x]
    return x


def _clean_text(text: str, out: Path) -> str:
    text = text.replace(str(out.resolve()), "<OUT>").replace(str(out), "<OUT>")
    run_dir = out.resolve().parent          # inputs that are other jobs of the same run (a synthesis result)
    text = text.replace(str(run_dir), "<RUN>")
    for pat, rep in VOLATILE_TEXT:
        text = pat.sub(rep, text)
    return text


def file_digest(path: Path, out: Path) -> str:
    h = hashlib.sha256()
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as z:
            for key in sorted(z.files):
                a = np.ascontiguousarray(z[key])
                kind = a.dtype.str
                if a.dtype.kind == "U":          # text (settings records) may name the run's directories
                    a = np.array([_clean_text(str(s), out) for s in a.ravel()]).reshape(a.shape)
                    kind = "U"
                h.update(f"{key}|{kind}|{a.shape}".encode())
                h.update(a.tobytes())
    elif path.suffix == ".json":
        data = json.loads(_clean_text(path.read_text(encoding="utf-8"), out).replace("<T>", "0"))
        h.update(json.dumps(_clean_json(data), sort_keys=True).encode())
    else:
        raw = path.read_bytes()
        try:
            raw = _clean_text(raw.decode("utf-8"), out).encode()
        except UnicodeDecodeError:
            pass
        h.update(raw)
    return h.hexdigest()


def run(out: Path, only: str | None) -> int:
    out.mkdir(parents=True, exist_ok=True)
    previous = out / "digests.json"      # a later run with --only adds to (or replaces) jobs of an earlier one
    digests: dict[str, dict[str, str]] = json.loads(previous.read_text()) if previous.is_file() else {}
    env = {**os.environ, "TORCHHAND_SHARED_DATA": str(SHARED)}
    failed = 0
    for name, cmd in jobs(out):
        if only and not re.search(only, name):
            continue
        d = out / name
        cmd = [c.replace("{dir}", str(d)) for c in cmd]
        if d.exists():
            print(f"{name}: {d} exists; delete it or choose another OUT", file=sys.stderr)
            return 2
        if "splice-accuracy" in name:
            d.mkdir()
        t0 = time.perf_counter()
        p = subprocess.run(cmd, cwd=out, capture_output=True, text=True, env=env)
        dt = time.perf_counter() - t0
        entry = {"<exit>": str(p.returncode), "<stdout>": hashlib.sha256(_clean_text(p.stdout, d).encode()).hexdigest()}
        (out / f"{name}.log").write_text(p.stdout + "\n--- stderr ---\n" + p.stderr, encoding="utf-8")
        if d.is_dir():
            for f in sorted(d.rglob("*")):
                if f.is_file():
                    entry[str(f.relative_to(d))] = file_digest(f, d)
        digests[name] = entry
        print(f"{name}: exit {p.returncode}, {len(entry) - 2} files, {dt:.0f} s", flush=True)
        failed += p.returncode not in (0, 1)
    (out / "digests.json").write_text(json.dumps(digests, indent=1, sort_keys=True), encoding="utf-8")
    print(f"wrote {out / 'digests.json'}")
    return 0


def rehash(out: Path) -> int:
    """Recompute the file digests of the jobs already in ``out`` (after a change of what counts as volatile)."""
    path = out / "digests.json"
    digests = json.loads(path.read_text())
    for name, entry in digests.items():
        d = out / name
        kept = {k: v for k, v in entry.items() if k.startswith("<")}
        if d.is_dir():
            kept.update({str(f.relative_to(d)): file_digest(f, d) for f in sorted(d.rglob("*")) if f.is_file()})
        digests[name] = kept
    path.write_text(json.dumps(digests, indent=1, sort_keys=True), encoding="utf-8")
    print(f"rehashed {len(digests)} jobs in {path}")
    return 0


def compare(a: Path, b: Path, only: str | None = None) -> int:
    da, db = json.loads(a.read_text()), json.loads(b.read_text())
    bad = 0
    for job in sorted(set(da) | set(db)):
        if only and not re.search(only, job):
            continue
        if job not in da or job not in db:
            print(f"{job}: only in {'A' if job in da else 'B'}")
            bad += 1
            continue
        ea, eb = da[job], db[job]
        diff = sorted(k for k in set(ea) | set(eb) if ea.get(k) != eb.get(k))
        print(f"{job}: {'identical' if not diff else 'DIFFERS: ' + ', '.join(diff)} ({len(ea) - 2} files)")
        bad += bool(diff)
    print(f"{bad} job(s) differ" if bad else "all jobs identical")
    return 1 if bad else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--only", help="run only the jobs whose name matches this regular expression")
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    c.add_argument("--only", help="compare only the jobs whose name matches this regular expression")
    h = sub.add_parser("rehash", help="recompute the file digests of the jobs already in OUT")
    h.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    if args.cmd == "rehash":
        return rehash(args.out)
    return run(args.out, args.only) if args.cmd == "run" else compare(args.a, args.b, args.only)


if __name__ == "__main__":
    sys.exit(main())
