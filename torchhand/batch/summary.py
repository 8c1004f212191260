"""The summary of a batch directory, from what is on disk: ``summary.csv`` (one row per job),
``summary_scenes.csv`` (one row per scene and a total), ``summary.md`` (both tables, the outcomes and the
failures) and ``summary.png`` (solutions and time per scene).

Every job of ``batch.json`` is one row, once, whatever happened to it: ``finished`` (its ``DIR/jobs/<id>/``
holds a complete result), ``unsuitable`` (a manipulate job whose grasp cannot realise the motion: a finished answer,
its partial result checked as far as it goes), ``failed`` (its last attempt failed; the error is the journal's), or
``pending``. For synthesize jobs the columns are Ye & Liu's Table 1 (2012) as ``stats.json`` holds them
(docs/result_format.md): solutions, dead ends, total frames (= node tests), success frames, success ratio, solution
ratio; then node tests per second of search. Every job has the method's wall time (``time_s``), the attempt's wall
time with the check (``job_s``, seconds), the thread count, the checker's verdict (``pass``: every solution
passes; ``fail``; ``none``: no solution to check) with its worst figure relative to its limit, and ``outcome``: the
method's answer in words (manipulate: frames and added contacts, or where the grasp failed; capture: rollouts
completed). Per scene, counts are summed and the ratios are those of the sums (success frames / total frames;
paths found / (paths found + dead ends)), not means of ratios.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from .._atomic import atomic_bytes
from .store import Journal, Layout, outcome, read_json
from .worker import UNSUITABLE

__all__ = ["JOB_COLUMNS", "SCENE_COLUMNS", "job_rows", "scene_rows", "write_summary"]

JOB_COLUMNS = ("job", "method", "scene", "seed", "hand", "input", "status", "attempts", "solutions", "dead_ends",
               "total_frames", "success_frames", "success_ratio", "solution_ratio", "paths_found", "node_tests_per_s",
               "time_s", "job_s", "threads", "device", "check", "check_worst", "check_worst_ratio", "outcome",
               "error")
SCENE_COLUMNS = ("scene", "jobs", "finished", "unsuitable", "failed", "solutions", "dead_ends", "total_frames", "success_frames",
                 "success_ratio", "solution_ratio", "node_tests_per_s", "time_s", "checks_passed")
_SUMS = ("solutions", "dead_ends", "total_frames", "success_frames", "paths_found", "time_s", "job_s")


def _worst(check: dict) -> tuple[str, float | None]:
    """The checker's figure that comes closest to (or goes furthest past) its limit, over every solution:
    ("object penetration 1.2 mm (limit 2.0 mm)", value / limit)."""
    from ..check.report import FIGURES, format_value

    best, text = None, ""
    for sol in check.get("solutions", []):
        for name, fig in sol.get("figures", {}).items():
            meta, value, limit = FIGURES.get(name), fig.get("value"), fig.get("limit")
            if meta is None or value is None or not limit:
                continue
            ratio = limit / max(value, 1e-12) if meta.at_least else value / limit
            if best is None or ratio > best:
                best = ratio
                text = f"{sol.get('file', '')}: {meta.label} {format_value(name, value)} " \
                       f"(limit {format_value(name, limit)})"
    return text, best


def job_rows(root) -> list[dict]:
    """One row per job of the batch in ``root`` (:data:`JOB_COLUMNS`), in manifest order."""
    layout = Layout(Path(root))
    batch = read_json(layout.batch_json) or {}
    events = Journal(layout.journal).read()
    rows = []
    for job in batch.get("jobs", []):
        jid = job["id"]
        mine = [e for e in events if e.get("job") == jid]
        ends = [e for e in mine if e.get("event") in ("finish", "fail")]
        d = layout.job_dir(jid)
        stats = read_json(d / "stats.json") or {}
        method = job.get("method", "synthesize")
        source = job.get("grasp") or job.get("interaction") or ""
        row = {"job": jid, "method": method, "scene": Path(job["scene"]).name, "seed": job.get("seed"),
               "hand": job["hand"], "input": "/".join(Path(source).parts[-2:]) if source else "",
               "attempts": sum(e.get("event") == "start" for e in mine)}
        state = outcome(d) if d.is_dir() else ""
        if state:
            check = read_json(d / "check.json") or {}
            meta = read_json(d / "job.json") or {}
            worst, ratio = _worst(check)
            row.update(status="finished" if state == "complete" else state, solutions=stats.get("solutions", 0),
                       time_s=stats.get("time_s"), job_s=meta.get("seconds"),
                       threads=stats.get("threads", meta.get("threads")), device=meta.get("device"),
                       check="none" if not check.get("solutions") else "pass" if check.get("passed") else "fail",
                       check_worst=worst, check_worst_ratio=ratio, outcome=_outcome(method, stats, d), error="")
            if method == "synthesize":
                row.update(dead_ends=stats.get("dead_ends"), total_frames=stats.get("total_frames"),
                           success_frames=stats.get("success_frames"), success_ratio=stats.get("success_ratio"),
                           solution_ratio=stats.get("solution_ratio"), paths_found=stats.get("paths_found"),
                           node_tests_per_s=stats.get("nodes_per_second"),
                           search_s=_search_share(stats.get("timings_s") or {}),
                           nodes_tested=stats.get("nodes_tested"))
        else:
            failed = bool(ends) and ends[-1].get("event") == "fail"
            row.update(status="failed" if failed else "pending", error=ends[-1].get("error", "") if failed else "")
        rows.append(row)
    return rows


def _search_share(timings: dict):
    """A job's seconds of search; a job of a group (``batch --group``) its share of the group's shared search."""
    search = timings.get("search_s")
    return None if search is None else search / timings.get("batched", 1)


def _outcome(method: str, stats: dict, d: Path) -> str:
    """The method's answer in words (module docstring)."""
    if method == "manipulate":
        bad = read_json(d / UNSUITABLE)
        if bad is not None:
            done = bad.get("frames_done") or 0
            return (bad.get("message") or f"grasp unsuitable at frame {bad.get('frame')}") + \
                (f" (frames 0-{done - 1} written and checked)" if done else " (no frame written)")
        return f"{stats.get('T')} frames, {stats.get('added_contacts', 0)} contact(s) added"
    if method == "capture":
        rolls = stats.get("rollouts") or []
        stopped = [f"rollout {i} stopped at step {r.get('failed_step')} ({r.get('failed_status')})"
                   for i, r in enumerate(rolls) if r.get("status") != "COMPLETED"]
        return f"{stats.get('solutions', 0)}/{len(rolls)} rollouts completed" + "".join(f"; {t}" for t in stopped)
    return ""


def scene_rows(rows: list[dict]) -> list[dict]:
    """Per-scene aggregates of :func:`job_rows` (:data:`SCENE_COLUMNS`), then a row ``"all"``."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(r["scene"], []).append(r)
    out = [_aggregate(name, group) for name, group in groups.items()]
    if len(groups) > 1:
        out.append(_aggregate("all", rows))
    return out


def _aggregate(name: str, group: list[dict]) -> dict:
    done = [r for r in group if r["status"] == "finished"]
    s = {k: sum(r.get(k) or 0 for r in done) for k in _SUMS}
    nodes, search = sum(r.get("nodes_tested") or 0 for r in done), sum(r.get("search_s") or 0 for r in done)
    checked = [r for r in group if r["status"] in ("finished", "unsuitable") and r["check"] != "none"]
    row = {"scene": name, "jobs": len(group), "finished": len(done),
            "unsuitable": sum(r["status"] == "unsuitable" for r in group),
            "failed": sum(r["status"] == "failed" for r in group), "solutions": s["solutions"],
            "dead_ends": s["dead_ends"], "total_frames": s["total_frames"], "success_frames": s["success_frames"],
            "success_ratio": s["success_frames"] / s["total_frames"] if s["total_frames"] else 0.0,
            "solution_ratio": s["paths_found"] / (s["paths_found"] + s["dead_ends"])
            if s["paths_found"] + s["dead_ends"] else 0.0,
            "node_tests_per_s": nodes / search if search else None, "time_s": s["time_s"],
            "checks_passed": f"{sum(r['check'] == 'pass' for r in checked)}/{len(checked)}"}
    if not any(r.get("method", "synthesize") == "synthesize" for r in group):      # no search: no Table 1 figures
        row.update(dict.fromkeys(("dead_ends", "total_frames", "success_frames", "success_ratio", "solution_ratio",
                                  "node_tests_per_s")))
    return row


def _csv(rows: list[dict], columns) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if r.get(k) is None else r.get(k) for k in columns})
    return buf.getvalue()


def _cell(key: str, value) -> str:
    if value is None or value == "":
        return "–"
    if key.endswith("_ratio") and isinstance(value, float):
        return f"{100 * value:.1f}%" if key != "check_worst_ratio" else f"{value:.2f}"
    if isinstance(value, float):
        return f"{value:.1f}"
    return str(value).replace("|", "\\|")


def _table(rows: list[dict], columns) -> str:
    lines = ["| " + " | ".join(c.replace("_", " ") for c in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_cell(c, r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def _markdown(root: Path, rows: list[dict], scenes: list[dict]) -> str:
    batch = read_json(root / "batch.json") or {}
    n = {s: sum(r["status"] == s for r in rows) for s in ("finished", "unsuitable", "failed", "pending")}
    methods = {r.get("method", "synthesize") for r in rows}
    drop = {"error", "check_worst_ratio", "device", "outcome"} | ({"method", "input"} if methods == {"synthesize"}
                                                                  else set())
    if "synthesize" not in methods:
        drop |= {"seed", "dead_ends", "total_frames", "success_frames", "success_ratio", "solution_ratio",
                 "paths_found", "node_tests_per_s"}
    cols = [c for c in JOB_COLUMNS if c not in drop]
    text = [f"# Batch summary: {root.name}", "",
            f"Manifest `{batch.get('manifest', {}).get('path', '')}`; {len(rows)} jobs: {n['finished']} finished, "
            + (f"{n['unsuitable']} unsuitable (grasp), " if n["unsuitable"] else "")
            + f"{n['failed']} failed, {n['pending']} pending. Synthesize columns as in Ye & Liu (2012), Table 1; "
            f"total frames are node tests; times in seconds (time s: the method, job s: the attempt with its "
            f"check).", "",
            "## Per scene", "", _table(scenes, SCENE_COLUMNS), "", "## Per job", "", _table(rows, cols), ""]
    answers = [r for r in rows if r.get("outcome")]
    if answers:
        text += ["## Outcomes", ""] + [f"- `{r['job']}` ({r['status']}): {r['outcome']}" for r in answers] + [""]
    failed = [r for r in rows if r["status"] == "failed"]
    if failed:
        text += ["## Failures", ""] + [f"- `{r['job']}`: {r['error']}" for r in failed] + [""]
    return "\n".join(text)


def _plot(scenes: list[dict]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    scenes = [s for s in scenes if s["scene"] != "all"]
    names = [s["scene"] for s in scenes]
    fig = Figure(figsize=(max(6.0, 1.2 * len(names) + 2), 3.6), tight_layout=True)
    for ax, key, label in ((fig.add_subplot(1, 2, 1), "solutions", "solutions (all jobs)"),
                           (fig.add_subplot(1, 2, 2), "time_s", "method time, s (all jobs)")):
        ax.bar(range(len(names)), [s[key] or 0 for s in scenes], color="#4878a8")
        ax.set_xticks(range(len(names)), names, rotation=30, ha="right")
        ax.set_title(label)
        if key == "solutions":
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def write_summary(root) -> list[Path]:
    """Write ``summary.csv``, ``summary_scenes.csv``, ``summary.md`` and ``summary.png`` into the batch
    directory ``root`` (atomically, each file whole), from what is on disk. Returns their paths."""
    root = Path(root)
    rows = job_rows(root)
    scenes = scene_rows(rows)
    files = {"summary.csv": _csv(rows, JOB_COLUMNS).encode(),
             "summary_scenes.csv": _csv(scenes, SCENE_COLUMNS).encode(),
             "summary.md": _markdown(root, rows, scenes).encode(), "summary.png": _plot(scenes)}
    for name, data in files.items():
        atomic_bytes(root / name, data)
    return [root / name for name in files]
