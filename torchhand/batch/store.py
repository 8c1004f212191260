"""The batch directory on disk: layout, the journal ``jobs.jsonl``, the batch lock, and exactly-once promotion.

::

    DIR/batch.json            the manifest's path and hash, the expanded jobs, every run's workers/threads/device
    DIR/batch.toml            a copy of the manifest
    DIR/jobs.jsonl            the journal: one JSON object a line (start, finish, fail, discard, batch), appended,
                              flushed and fsynced line by line
    DIR/jobs/<id>/            a finished job: a complete result directory (docs/result_format.md) plus
                              check.json (the checker's report) and job.json (the job, attempt, threads, device);
                              or, for a manipulate job whose grasp is unsuitable, unsuitable.json (and the partial
                              result with its check.json, when frames were done before the grasp failed)
    DIR/jobs/.staging/<id>.<n>/   attempt n of a job being written
    DIR/logs/<id>.<n>.log     stdout and stderr of attempt n
    DIR/.batch.lock           held (flock) by the running batch process

Exactly once: an attempt writes only into its own staging directory; a finished attempt (``stats.json`` says
``"complete": true`` and ``check.json`` is there, or the worker wrote ``unsuitable.json``, :func:`outcome`) is moved to ``DIR/jobs/<id>/`` with one ``os.rename`` (atomic on
one filesystem), and only then is its ``finish`` line written. Only the process holding the batch lock promotes,
and it never promotes over an existing ``DIR/jobs/<id>/``. A killed attempt leaves at most a staging directory,
which the next run removes with a ``discard`` line (or promotes, when the attempt had completed before the batch
process died). An attempt is alive while its log file is locked: the lock is taken by the batch process and
inherited by the worker, so it is released when the worker ends, however it ends.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import hashlib
import json
import os
import shutil
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from .._atomic import atomic_json, atomic_text, writable_dir
from ..errors import InputValueError
from .manifest import Job, Manifest
from .worker import UNSUITABLE, run_device

__all__ = ["BATCH_FORMAT", "outcome", "Layout", "Journal", "validate_out", "open_batch", "recover", "finish_attempt",
           "log_busy", "read_json", "now"]

BATCH_FORMAT = 1
"""Version of ``batch.json``."""


def now() -> str:
    """The time as ISO 8601 with the UTC offset, milliseconds."""
    return _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class Layout:
    """Paths of a batch directory ``root`` (module docstring)."""

    root: Path

    @property
    def jobs(self) -> Path:
        return self.root / "jobs"

    @property
    def staging(self) -> Path:
        return self.root / "jobs" / ".staging"

    @property
    def logs(self) -> Path:
        return self.root / "logs"

    @property
    def journal(self) -> Path:
        return self.root / "jobs.jsonl"

    @property
    def batch_json(self) -> Path:
        return self.root / "batch.json"

    def job_dir(self, job_id: str) -> Path:
        return self.jobs / job_id

    def stage(self, job_id: str, attempt: int) -> Path:
        return self.staging / f"{job_id}.{attempt}"

    def log(self, job_id: str, attempt: int) -> Path:
        return self.logs / f"{job_id}.{attempt}.log"


class Journal:
    """``DIR/jobs.jsonl``: append-only, one JSON object a line, each line flushed and fsynced before
    :meth:`append` returns. :meth:`read` skips a torn last line (a process killed while writing)."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def append(self, event: str, **fields) -> dict:
        record = {"time": now(), "event": event, **fields}
        line = json.dumps(record, separators=(", ", ": ")) + "\n"
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            if os.fstat(fd).st_size and not self._ends_with_newline():
                line = "\n" + line                       # after a torn line
            os.write(fd, line.encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        return record

    def _ends_with_newline(self) -> bool:
        with open(self.path, "rb") as fh:
            fh.seek(-1, os.SEEK_END)
            return fh.read(1) == b"\n"

    def read(self) -> list[dict]:
        if not self.path.is_file():
            return []
        out = []
        for line in self.path.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(record, dict):
                out.append(record)
        return out


def read_json(path: Path) -> dict | None:
    """The JSON object in ``path``, or None when it is missing or unreadable."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def outcome(result_dir: Path) -> str:
    """What a job's (or an attempt's) directory holds: ``"complete"`` (``stats.json`` says ``"complete": true``),
    ``"unsuitable"`` (the worker's ``unsuitable.json``: a manipulate job whose grasp cannot realise the motion, a
    finished answer) or ``""`` (nothing finished)."""
    if read_json(Path(result_dir) / UNSUITABLE) is not None:
        return "unsuitable"
    stats = read_json(Path(result_dir) / "stats.json")
    return "complete" if stats is not None and stats.get("complete") is True else ""


def _complete(result_dir: Path) -> str:
    """"" when ``result_dir`` holds a finished attempt, else why not."""
    if read_json(result_dir / UNSUITABLE) is not None:
        return ""                                                # written last, after any check.json
    stats = read_json(result_dir / "stats.json")
    if stats is None:
        return "no readable stats.json"
    if stats.get("complete") is not True:
        return 'stats.json says "complete": false'
    if read_json(result_dir / "check.json") is None:
        return "no check.json (the checker did not finish)"
    return ""


def validate_out(out: Path, manifest: Manifest, *, update: bool) -> None:
    """Check ``--out`` before any work, writing nothing: not a file; empty, new, or a batch directory whose jobs
    are this manifest's (another manifest's batch only with ``update``). InputValueError otherwise."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputValueError(f"--out {out}: exists and is not a directory")
    if not out.is_dir():
        return
    old = read_json(out / "batch.json")
    if old is None:
        if any(p.name != ".batch.lock" for p in out.iterdir()):
            raise InputValueError(f"--out {out}: exists, is not empty and is not a batch directory (no batch.json); "
                                  f"choose a new directory (nothing was written)")
        return
    old_ids = {j.get("id") for j in old.get("jobs", [])}
    new_ids = set(manifest.ids)
    if old_ids != new_ids and not update:
        raise InputValueError(
            f"--out {out}: holds the batch of another manifest ({len(old_ids)} jobs, {len(old_ids & new_ids)} of "
            f"them in {manifest.path.name}'s {len(new_ids)}); choose a new --out, or pass --update to make this "
            f"manifest the batch's (finished jobs it shares are kept)")


def _lock(layout: Layout):
    fh = open(layout.root / ".batch.lock", "a+")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip()
        fh.close()
        raise InputValueError(f"--out {layout.root}: another torchhand batch is running on it"
                              f"{f' ({holder})' if holder else ''}; wait for it or choose another directory") from None
    fh.seek(0)
    fh.truncate()
    fh.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
    fh.flush()
    return fh


def open_batch(out: Path, manifest: Manifest, run: dict, *, update: bool) -> tuple[Layout, Journal, object]:
    """Create or reopen the batch directory ``out`` for ``manifest`` (validated as :func:`validate_out`), take
    the batch lock (InputValueError when another batch process holds it), and record the manifest, its jobs and
    this run (``run``: workers, threads, device, backend, ...) in ``batch.json``. Returns the layout, the
    journal and the lock's file (held until it is closed or the process ends)."""
    validate_out(out, manifest, update=update)
    layout = Layout(writable_dir(out).resolve())
    lock = _lock(layout)
    validate_out(out, manifest, update=update)              # again, now that no other batch can change it
    journal = Journal(layout.journal)
    old = read_json(layout.batch_json) or {}
    if old and {j.get("id") for j in old.get("jobs", [])} != set(manifest.ids):
        journal.append("manifest", action="update", old_manifest_sha256=old.get("manifest", {}).get("sha256"),
                       jobs=len(manifest.jobs))
    for d in (layout.jobs, layout.staging, layout.logs):
        d.mkdir(parents=True, exist_ok=True)
    from .. import __version__

    runs = list(old.get("runs", [])) + [{"started": now(), "torchhand": __version__, "host": socket.gethostname(),
                                         "pid": os.getpid(), **run}]
    atomic_text(layout.root / "batch.toml", manifest.text)
    atomic_json(layout.batch_json, {
        "format_version": BATCH_FORMAT,
        "manifest": {"path": str(manifest.path), "sha256": hashlib.sha256(manifest.text.encode()).hexdigest(),
                     "copy": "batch.toml"},
        "jobs": [j.to_dict() for j in manifest.jobs],
        "runs": runs,
    })
    return layout, journal, lock


def log_busy(path: Path) -> bool:
    """Whether a live process holds the lock of an attempt's log file (the attempt is still running)."""
    if not path.is_file():
        return False
    with open(path, "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
    return False


def _attempts_on_disk(layout: Layout) -> dict[str, int]:
    """Job id -> the highest attempt number of a staging directory or a log file."""
    out: dict[str, int] = {}
    for folder, suffix in ((layout.staging, ""), (layout.logs, ".log")):
        for p in folder.iterdir() if folder.is_dir() else ():
            name = p.name[: -len(suffix)] if suffix and p.name.endswith(suffix) else p.name
            job_id, _, n = name.rpartition(".")
            if job_id and n.isdigit():
                out[job_id] = max(out.get(job_id, 0), int(n))
    return out


def _remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


def recover(layout: Layout, journal: Journal, jobs: tuple[Job, ...], *, grace_s: float = 10.0,
            note=lambda line: None) -> tuple[set[str], dict[str, int]]:
    """Bring the directory to a clean state after whatever happened before, and say what is left to do.

    1. An attempt whose worker was launched but whose ``start`` line was never written gets it (``"late": true``).
    2. A ``DIR/jobs/<id>/`` that is not a complete result (not written by this module) is moved to
       ``DIR/jobs/.discarded/``.
    3. Staging directories of earlier attempts are promoted (the attempt had completed: a ``finish`` line with
       ``"recovered": true``), removed (partial, or the job is already finished: a ``discard`` line) or, while
       their worker still runs (waited for up to ``grace_s`` seconds), left alone (``discard`` with ``"left"``).
    4. Every other ``start`` without an end gets its ``fail`` line (``"late": true``).

    Returns (ids of finished jobs, job id -> the next attempt number).
    """
    by_id = {j.id: j for j in jobs}
    starts = _record_unlogged_starts(layout, journal, by_id)
    _set_aside_broken(layout, journal, by_id, note)
    left = _clean_staging(layout, journal, by_id, starts, grace_s, note)
    _close_dangling(layout, journal, starts, left, grace_s)
    finished = {i for i in by_id if not _complete_result(layout.job_dir(i))}
    on_disk = _attempts_on_disk(layout)
    counts: dict[str, int] = {}
    for e in journal.read():
        if e.get("event") == "start":
            counts[e["job"]] = max(counts.get(e["job"], 0), int(e["attempt"]))
    return finished, {i: max(counts.get(i, 0), on_disk.get(i, 0)) + 1 for i in by_id}


def _record_unlogged_starts(layout: Layout, journal: Journal, by_id: dict) -> dict:
    """(job, attempt) -> start record, after adding those of attempts that have a log file but no line (the
    batch process was killed between launching the worker and writing the line)."""
    starts = {(e["job"], e["attempt"]): e for e in journal.read() if e.get("event") == "start"}
    for log in sorted(layout.logs.glob("*.log")):
        job_id, _, n = log.name[:-4].rpartition(".")
        if job_id in by_id and n.isdigit() and (job_id, int(n)) not in starts:
            starts[(job_id, int(n))] = journal.append(
                "start", job=job_id, attempt=int(n), late=True, log=str(log.relative_to(layout.root)),
                note="recorded at recovery: the batch process ended before it wrote this line")
    return starts


def _set_aside_broken(layout: Layout, journal: Journal, by_id: dict, note) -> None:
    for job_id in by_id:
        d = layout.job_dir(job_id)
        if d.exists() and _complete_result(d):
            aside = layout.jobs / ".discarded" / f"{job_id}.{time.strftime('%Y%m%d-%H%M%S')}"
            aside.parent.mkdir(exist_ok=True)
            os.rename(d, aside)
            journal.append("discard", job=job_id, reason=f"DIR/jobs/{job_id} was not a complete result (not "
                           f"written by torchhand batch); moved to {aside.relative_to(layout.root)}")
            note(f"moved the incomplete {d} to {aside}")


def _clean_staging(layout: Layout, journal: Journal, by_id: dict, starts: dict, grace_s: float, note) -> set:
    """Promote, remove or leave every staging directory (:func:`recover`, step 3); returns the attempts left."""
    left = set()
    for name in sorted(os.listdir(layout.staging)) if layout.staging.is_dir() else ():
        job_id, _, n = name.rpartition(".")
        stage = layout.staging / name
        if not (job_id and n.isdigit() and stage.is_dir()):
            continue
        n = int(n)
        deadline = time.monotonic() + grace_s
        while log_busy(layout.log(job_id, n)) and time.monotonic() < deadline:
            time.sleep(0.1)
        if log_busy(layout.log(job_id, n)):
            journal.append("discard", job=job_id, attempt=n, left=True,
                           reason="its worker is still running (a process of an earlier batch run); left alone")
            note(f"attempt {n} of {job_id} is still being written by another process; left alone")
            left.add((job_id, n))
            continue
        why = _complete(stage)
        if job_id in by_id and not why and not layout.job_dir(job_id).exists():
            start = starts.get((job_id, n), {})
            finish_attempt(layout, journal, by_id[job_id], n, returncode=0, recovered=True,
                           meta={"threads": start.get("threads"), "device": start.get("device"),
                                 "backend": start.get("backend"), "started": start.get("time")})
            note(f"{job_id}: attempt {n} had completed before the batch process ended; kept")
            continue
        reason = "the job is already finished" if layout.job_dir(job_id).exists() else \
            "not a job of this batch" if job_id not in by_id else f"partial ({why})"
        _remove(stage)
        journal.append("discard", job=job_id, attempt=n, reason=f"staging directory removed: {reason}")
        note(f"removed {stage} ({reason})")
    return left


def _close_dangling(layout: Layout, journal: Journal, starts: dict, left: set, grace_s: float = 10.0) -> None:
    """A ``finish`` (the result is in place) or a late ``fail`` for every start without an end. An attempt whose log
    is still locked (a process of the killed run that has not exited yet) is waited for up to ``grace_s`` seconds,
    as in :func:`_clean_staging`; still locked then, it is left to that process."""
    events = journal.read()
    ended = {(e.get("job"), e.get("attempt")) for e in events if e.get("event") in ("finish", "fail")}
    finished_ids = {e.get("job") for e in events if e.get("event") == "finish"}
    for (job_id, n) in starts:
        if (job_id, n) in ended or (job_id, n) in left:
            continue
        deadline = time.monotonic() + grace_s
        while log_busy(layout.log(job_id, n)) and time.monotonic() < deadline:
            time.sleep(0.1)
        if log_busy(layout.log(job_id, n)):
            continue
        meta = read_json(layout.job_dir(job_id) / "job.json") or {}
        if meta.get("attempt") == n and job_id not in finished_ids:
            journal.append("finish", job=job_id, attempt=n, recovered=True, note="the result was in place; the "
                           "batch process ended before it wrote this line")
        else:
            journal.append("fail", job=job_id, attempt=n, late=True,
                           error="the attempt ended without a record (the batch process was killed or crashed)")


def _complete_result(result_dir: Path) -> str:
    """"" when ``result_dir`` is a finished job's directory (:func:`outcome`), else why not."""
    if not result_dir.is_dir():
        return "missing"
    return "" if outcome(result_dir) else "incomplete"


def finish_attempt(layout: Layout, journal: Journal, job: Job, attempt: int, *, returncode: int | None,
                   error: str = "", meta: dict | None = None, recovered: bool = False) -> dict:
    """Record the end of attempt ``attempt`` of ``job``: promote its staging directory to ``DIR/jobs/<id>/`` and
    write the ``finish`` line, or remove it and write the ``fail`` line (``error``; ``returncode`` of the worker,
    negative for a signal). Returns the journal record."""
    stage = layout.stage(job.id, attempt)
    why = error or (_complete(stage) if returncode == 0 else f"worker exited with {returncode}")
    if not why and layout.job_dir(job.id).exists():
        _remove(stage)
        return journal.append("discard", job=job.id, attempt=attempt,
                              reason="staging directory removed: the job is already finished")
    if why:
        existed = stage.exists()
        _remove(stage)
        return journal.append("fail", job=job.id, attempt=attempt, returncode=returncode, error=why,
                              log=str(layout.log(job.id, attempt).relative_to(layout.root)),
                              **({"staging": "removed"} if existed else {}))
    stats = read_json(stage / "stats.json") or {}
    check = read_json(stage / "check.json") or {}
    result = outcome(stage)
    meta = dict(meta or {})
    if meta.get("device") is not None:
        meta["device"] = run_device(job.method, meta["device"])
    info = {"id": job.id, "attempt": attempt, **meta, "finished": now(), "outcome": result,
            "log": str(layout.log(job.id, attempt).relative_to(layout.root)), "job": job.to_dict()}
    atomic_json(stage / "job.json", info)
    os.rename(stage, layout.job_dir(job.id))                     # atomic: the whole result appears at once
    _fsync_dir(layout.jobs)
    return journal.append("finish", job=job.id, attempt=attempt, solutions=stats.get("solutions", 0),
                          check="none" if not check.get("solutions") else "pass" if check.get("passed") else "fail",
                          seconds=meta.get("seconds"), **({"outcome": result} if result != "complete" else {}),
                          **({"recovered": True} if recovered else {}))


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
