"""Progress of a batch run: :class:`Counts` after each event, and the tracker that keeps them, the ETA and the
ids finished, failed and unsuitable, and tells the caller's ``notify`` (local pool and Ray backend alike)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

__all__ = ["Counts"]


@dataclass(frozen=True)
class Counts:
    """Progress of a run, after an event.

    total: jobs in the batch; done: finished (earlier runs included); running: attempts running; failed: attempts
    failed in this run; ran: attempts ended in this run; elapsed_s: seconds since the run started; eta_s:
    estimated seconds left (from the rate of attempts ending in this run; None before the first)
    """

    total: int
    done: int = 0
    running: int = 0
    failed: int = 0
    ran: int = 0
    elapsed_s: float = 0.0
    eta_s: float | None = None


class _Tracker:
    """Counts, ETA and the event callback ``notify(kind, job_id, record, counts)``."""

    def __init__(self, total: int, done: int, notify):
        self.counts = Counts(total=total, done=done)
        self.t0 = time.monotonic()
        self.notify = notify or (lambda *a: None)
        self.finished: list[str] = []
        self.failed: list[str] = []
        self.unsuitable: list[str] = []

    def event(self, kind: str, job_id: str, record: dict | None = None) -> None:
        c = self.counts
        done, running, failed, ran = c.done, c.running, c.failed, c.ran
        if kind == "start":
            running += 1
        elif kind in ("finish", "fail", "discard"):
            running, ran = running - 1, ran + 1
            if kind in ("finish", "discard"):          # discard: the job had been finished meanwhile
                done += 1
                self.finished.append(job_id)
                if (record or {}).get("outcome") == "unsuitable":
                    self.unsuitable.append(job_id)
            else:
                failed += 1
                self.failed.append(job_id)
        elapsed = time.monotonic() - self.t0
        left = c.total - done - failed
        eta = 0.0 if not left else elapsed / ran * left if ran else None
        self.counts = replace(c, done=done, running=running, failed=failed, ran=ran, elapsed_s=elapsed, eta_s=eta)
        self.notify(kind, job_id, record or {}, self.counts)
