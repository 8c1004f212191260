"""Which solutions of a synthesis result does interaction resynthesis (Kry & Pai 2006) follow on the same object?

For every solution of a ``torchhand synthesize`` result (e.g. the README's ``torchhand synthesize box-turn``, ten
solutions): ``capture from-result`` over the solution's loaded frames (3 frames either side, as
``scripts/demo_inferred.py`` takes them), then ``capture resynthesize`` on the result's own scene (the same object,
dt 1/240 s, Lemke, 8 settle steps), then ``torchhand check``. One row per solution: the reference's turn and the
resynthesised object's (and its share of the reference's), the largest lag behind the reference's turn, the largest
object slip in the hand frame, the checker's verdict and its failing figures, and the share of frames in which each
finger pushes the object with more than 0.2 N, in the reference and in the resynthesis.

    python scripts/survey_inferred.py RESULT --out DIR [--solutions 0,3,6] [--dt 1/240] [--overwrite]
        [--resynth-args "--reach --close-open"]

Writes DIR/inf<i>/ (the inferred interaction), DIR/same<i>/ (the resynthesis, a result directory),
DIR/summary.json (atomically) and DIR/survey.png (turn and slip per solution, the marks of 10 % and 5 mm drawn).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from demo_inferred import _cli, contacts_per_finger, loaded_frames, turn_and_lift, turn_lag  # noqa: E402


def _fraction(text: str) -> float:
    num, _, den = text.partition("/")
    return float(num) / float(den or 1)


def survey_one(result: Path, i: int, out: Path, dt: float, over: list, extra: list) -> dict:
    """One solution: inferred, resynthesised on the same object, checked; the row's figures."""
    from torchhand.check import check_result
    from torchhand.io.result import load_result

    frames = loaded_frames(result, i)
    inferred, dest = out / f"inf{i}", out / f"same{i}"
    if _cli(["capture", "from-result", str(result), "--solution", str(i), "--frames", frames, "--out",
             str(inferred), *over]) != 0:
        return {"solution": i, "frames": frames, "completed": False, "why": "from-result failed"}
    rc = _cli(["capture", "resynthesize", str(inferred / "interaction.npz"), "--scene", str(inferred / "scene"),
               "--out", str(dest), "--dt", repr(dt), "--solver", "lemke", "--settle-steps", "8", *extra, *over])
    stats = json.loads((dest / "stats.json").read_text()) if (dest / "stats.json").is_file() else {}
    roll = (stats.get("rollouts") or [{}])[0]
    if rc != 0 or roll.get("status") != "COMPLETED":
        return {"solution": i, "frames": frames, "completed": False,
                "why": f"stopped at step {roll.get('failed_step')} ({roll.get('failed_status')})"}
    ref_res = load_result(result)
    ref = ref_res.solution(i)
    a, b = (int(x) for x in frames.split(":"))
    sol = load_result(dest).solution(0)
    ref_turn, _ = turn_and_lift(ref.object_pose[a:b])
    turn, _ = turn_and_lift(sol.object_pose)
    lag_max, _ = turn_lag(sol.object_pose, dt, ref.object_pose[a:b], float(ref_res.scene.fps))
    report = check_result(dest).solutions[0]
    return {"solution": i, "frames": frames, "completed": True, "ref_turn_deg": ref_turn, "turn_deg": turn,
            "turn_share": turn / ref_turn if ref_turn > 0 else float("nan"), "lag_deg_max": lag_max,
            "max_slip_mm": 1e3 * roll["max_object_slip_m"], "check_passed": report.passed,
            "failing": [n for n, x in report.figures.items() if not x.ok],
            "fingers_reference": contacts_per_finger(_Window(ref, a, b)), "fingers": contacts_per_finger(sol),
            "per_step_ms": stats.get("per_step_ms")}


class _Window:
    """The frames a <= t < b of a solution, for :func:`contacts_per_finger`."""

    def __init__(self, sol, a: int, b: int):
        self._sol, self.T = sol, b - a
        self.contact_force = sol.contact_force[a:b]
        self.contact_mask = sol.contact_mask[a:b]
        self.contact_link = np.asarray(sol.contact_link)[a:b] if np.ndim(sol.contact_link) > 1 else sol.contact_link

    def contact_link_names(self):
        return self._sol.contact_link_names()


def plot(rows: list, path: Path) -> None:
    """Turn (share of the reference's) and slip per solution, with the 10 % and 5 mm marks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = [r for r in rows if r["completed"]]
    x = np.arange(len(done))
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    ax1.bar(x, [100 * r["turn_share"] for r in done],
            color=["tab:green" if abs(1 - r["turn_share"]) <= 0.1 else "tab:gray" for r in done])
    ax1.axhspan(90, 110, color="tab:green", alpha=0.15, label="within 10 % of the reference")
    ax1.set_ylabel("turn, % of reference")
    ax1.legend(loc="upper left", fontsize=8)
    ax2.bar(x, [r["max_slip_mm"] for r in done],
            color=["tab:green" if r["max_slip_mm"] <= 5 else "tab:gray" for r in done])
    ax2.axhline(5, color="tab:green", lw=1, label="5 mm")
    ax2.set_ylabel("max slip, mm")
    ax2.set_xticks(x, [f"{r['solution']}{'' if r['check_passed'] else '*'}" for r in done])
    ax2.set_xlabel("solution (* fails torchhand check)")
    ax2.legend(loc="upper left", fontsize=8)
    fig.suptitle("Resynthesis on the same object, per solution")
    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    os.replace(tmp, path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", help="a `torchhand synthesize` result directory (one hand)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--solutions", default=None, help="comma-separated solution indices (default: all)")
    p.add_argument("--dt", default="1/240", help="resynthesis step, seconds (1/240)")
    p.add_argument("--overwrite", action="store_true", help="replace earlier outputs")
    p.add_argument("--resynth-args", default="", help="more `capture resynthesize` flags, e.g. \"--reach\"")
    a = p.parse_args(argv)
    from torchhand.io.result import load_result

    result, out = Path(a.result), Path(a.out)
    n = len(load_result(result).solutions)
    picks = [int(s) for s in a.solutions.split(",")] if a.solutions else list(range(n))
    bad = [i for i in picks if not 0 <= i < n]
    if bad:
        print(f"survey_inferred: --solutions: {result} has solutions 0-{n - 1}, not {bad}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    over = ["--overwrite"] if a.overwrite else []
    rows = [survey_one(result, i, out, _fraction(a.dt), over, a.resynth_args.split()) for i in picks]
    print(f"\n{'sol':>3}  {'frames':<7} {'ref turn':>8} {'turn':>6} {'share':>6} {'lag max':>7} {'slip mm':>7}  "
          f"{'check':<5}  fingers: reference -> resynthesis")
    for r in rows:
        if not r["completed"]:
            print(f"{r['solution']:>3}  {r['frames']:<7} {r['why']}")
            continue
        print(f"{r['solution']:>3}  {r['frames']:<7} {r['ref_turn_deg']:8.1f} {r['turn_deg']:6.1f} "
              f"{100 * r['turn_share']:5.0f}% {r['lag_deg_max']:7.1f} {r['max_slip_mm']:7.1f}  "
              f"{'pass' if r['check_passed'] else 'FAIL':<5}  {r['fingers_reference']} -> {r['fingers']}"
              + ("" if r["check_passed"] else f"  (fails: {', '.join(r['failing'])})"))
    done = [r for r in rows if r["completed"]]
    follow = [r for r in done if abs(1 - r["turn_share"]) <= 0.1 and r["max_slip_mm"] <= 5 and r["check_passed"]]
    print(f"\n{len(follow)} of {len(rows)} follow the reference (turn within 10 %, slip <= 5 mm, check passed)")
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps({"result": str(result), "dt": _fraction(a.dt), "resynth_args": a.resynth_args,
                               "rows": rows}, indent=1, default=float))
    os.replace(tmp, out / "summary.json")
    if done:
        plot(rows, out / "survey.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
