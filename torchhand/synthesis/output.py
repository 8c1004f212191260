"""Result directories of ``torchhand synthesize``: the writer of the format in ``docs/result_format.md``.

:class:`ResultWriter` writes a result directory so that nothing is lost:

* the output is validated before any work (:meth:`ResultWriter.__init__`: an existing result directory is replaced
  only with ``overwrite``; a directory that is not a result directory is never replaced; an unwritable place fails
  at once);
* solutions are checkpointed as they are accepted: each ``solutions/sol_XXX.npz`` and a ``stats.json`` with
  ``"complete": false`` are written at once, so an interrupted run (Ctrl-C, ``kill -9``, a crash) leaves every
  solution found so far readable;
* every file is written to a temporary name in its folder and moved into place with ``os.replace``;
* a new directory is written in place; a replaced one is built beside it (``DIR.partial``) and swapped in only
  when complete, so the old result stays whole until then (an interrupted run leaves it untouched and its
  checkpoints in ``DIR.partial``).
"""

from __future__ import annotations

import fcntl
import io
import math
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from .._atomic import atomic_bytes, atomic_json
from .._numerics import record as numerics_record
from ..errors import InputValueError, TorchhandError
from ..hand.mjcf import hand_to_mjcf
from ..io.result import FORMAT_VERSION
from .node_test import contact_slots
from ._diversity import diversity
from .problem import SynthesisProblem

if TYPE_CHECKING:  # pragma: no cover
    from .pipeline import SynthesisResult

__all__ = ["MAX_CONTACTS", "ResultWriter", "solution_arrays", "solution_view", "stats_dict", "write_result"]

MAX_CONTACTS = 32
"""K, the most hand contacts written per frame."""


_atomic_bytes = atomic_bytes
_atomic_json = atomic_json


def solution_arrays(result: SynthesisResult, index: int) -> dict:
    """The npz arrays of solution ``index`` (docs/result_format.md)."""
    p = result.problem
    sol = result.finals[index]
    T = sol.q.shape[0]
    H = p.H
    hands = p.hands
    names = []
    for h, hand in enumerate(hands):
        names += [(f"{p.sides[h]}/" if H > 1 else "") + n for n in hand.link_names]
    mask = sol.c_mask.cpu()
    counts = mask.sum(-1)
    K = int(counts.max()) if T else 0
    if K > MAX_CONTACTS:
        raise InputValueError(f"a frame has {K} hand contacts, more than the {MAX_CONTACTS} the format holds")
    order = torch.sort((~mask).to(torch.int8), dim=-1, stable=True).indices[:, :K]      # contacts first
    take = lambda x: torch.gather(x.cpu(), 1, order[..., None].expand(-1, -1, x.shape[-1]) if x.dim() == 3 else order)
    c_mask = torch.gather(mask, 1, order)
    slot_hand, slot_link = contact_slots(p)
    offsets = torch.tensor([0] + [hd.num_links for hd in hands[:-1]]).cumsum(0)
    slot_name = (offsets[slot_hand.cpu()] + slot_link.cpu())                              # index into the names
    link = torch.where(c_mask, slot_name[order], torch.full_like(order, -1))
    f = lambda x: x.detach().double().cpu().numpy()
    m3 = c_mask[..., None].double()
    out = {
        "format_version": np.array(FORMAT_VERSION),
        "joint_names": np.array(hands[0].joint_names),
        "object_pose": f(p.object_pose), "fps": np.array(p.fps),
        "contact_mask": c_mask.numpy(), "contact_link": link.numpy(), "contact_link_name": np.array(names),
        "contact_point": f(take(sol.c_point) * m3), "contact_normal": f(take(sol.c_normal) * m3),
        "contact_force": f(take(sol.c_force) * m3),
        "contact_sliding": torch.gather(sol.sliding.cpu(), 1, order).numpy() & c_mask.numpy(),
        "env_contact_mask": p.env.mask.cpu().numpy(), "env_contact_point": f(p.env.points),
        "env_contact_force": f(sol.env_force * p.env.mask[..., None].to(sol.env_force.dtype)),
        "strategy": np.array(result.settings.strategy), "friction": np.array(p.friction),
        "reconstructed": np.array(bool(sol.reconstructed)),
    }
    first = p.sides.index("right") if "right" in p.sides else 0
    out["q"] = f(sol.q[:, first])
    out["root_pose"] = f(p.root[first])
    out["guiding"] = sol.guiding[:, first].cpu().numpy()
    if H > 1:
        for h, side in enumerate(p.sides):
            out[f"q_{side}"] = f(sol.q[:, h])
            out[f"root_pose_{side}"] = f(p.root[h])
            out[f"guiding_{side}"] = sol.guiding[:, h].cpu().numpy()
    out.update(captured_roots(result.scene, p.sides))
    if result.scene.captured_object_pose is not None:
        out["object_pose_captured"] = result.scene.captured_object_pose.detach().double().cpu().numpy()
    return out


def captured_roots(scene, sides) -> dict:
    """``root_pose_captured`` (the first hand in the order of ``q``: the right one if present) and, with two hands,
    ``root_pose_captured_<side>``, (T, 4, 4) float64, for hands whose wrist track was moved from the capture
    (``HandTrack.captured_wrist_pose``); {} when none was."""
    tracks = {h.side: h for h in scene.hands}
    if all(tracks[s].captured_wrist_pose is None for s in sides):
        return {}
    get = lambda s: (tracks[s].captured_wrist_pose if tracks[s].captured_wrist_pose is not None
                     else tracks[s].wrist_pose).detach().double().cpu().numpy()
    first = "right" if "right" in sides else sides[0]
    out = {"root_pose_captured": get(first)}
    if len(sides) > 1:
        out.update({f"root_pose_captured_{s}": get(s) for s in sides})
    return out


def solution_view(result: SynthesisResult, index: int):
    """Solution ``index`` as the result contract's :class:`torchhand.io.result.Solution` (NumPy), as a reader of the
    written file would see it."""
    from ..io.result import solution_from_arrays
    return solution_from_arrays(solution_arrays(result, index), Path(f"sol_{index:03d}.npz"))


def stats_dict(result: SynthesisResult, *, threads: int | None = None) -> dict:
    """stats.json: the paper's Table 1 columns for the run and more (docs/result_format.md)."""
    st = result.stats
    found = st.paths_found
    search_s = result.timings.get("search_s", st.time_s)
    scene = result.scene
    ex = result.excluded
    return {
        "format_version": FORMAT_VERSION, "complete": bool(result.complete),
        "scene": scene.name, "epsilon": result.settings.epsilon, "T": scene.T, "time_s": result.timings.get("total_s"),
        "solutions": len(result.finals), "paths_found": found, "excluded": ex.total,
        "excluded_by_reason": {"failed_check": ex.failed_check, "unsmoothed": ex.unsmoothed,
                               "duplicate": ex.duplicate},
        "dead_ends": st.dead_ends, "total_frames": st.nodes_tested, "success_frames": st.success_frames,
        "success_ratio": st.success_frames / st.nodes_tested if st.nodes_tested else 0.0,
        "solution_ratio": found / (found + st.dead_ends) if found + st.dead_ends else 0.0,
        "nodes_tested": st.nodes_tested,
        "nodes_per_second": result.timings.get("batch_nodes", st.nodes_tested) / search_s if search_s else 0.0,
        "max_nodes": result.settings.max_nodes, "time_budget": result.settings.time_budget,
        "stopped_by": st.stopped_by,
        "rejections": dict(st.rejections), "diversity_m": _finite(diversity(result.finals)),
        "reconstructed": [bool(s.reconstructed) for s in result.finals],
        "unsmoothed": [i for i, s in enumerate(result.finals) if not s.reconstructed],
        "max_joint_speed": result.max_joint_speed, "keep_unsmoothed": result.keep_unsmoothed,
        "restarts": st.restarts, "deepest_frame": st.deepest_frame, "strategy": result.settings.strategy,
        "seed": result.seed, "threads": threads if threads is not None else torch.get_num_threads(),
        "numerics": numerics_record(),
        "timings_s": result.timings, "trees": result.settings.trees, "candidates": result.settings.candidates,
        "slide_speed": result.node_settings.slide_speed,
        "rejections_by_frame": [list(r) for r in st.rejections_by_frame],
        "mount": {t.side: (list(t.mount) if t.mount is not None else None) for t in scene.hands},
        "rest": {t.side: t.rest for t in scene.hands},
        "mount_fit": [{"side": f.side, "mount": list(f.mount), "rest": f.rest, "score": f.score,
                       "score_unmoved": f.score_unmoved,
                       "reach": list(f.reach), "reach_unmoved": list(f.reach_unmoved), "frames": list(f.frames)}
                      for f in result.mount_fits],
    }


def _finite(x):
    return None if x is None or not math.isfinite(x) else x


_LOCK = ".torchhand.lock"


def _is_result_dir(path: Path) -> bool:
    return (path / "stats.json").is_file() or ((path / "scene").is_dir() and (path / "solutions").is_dir())


def _locked_by_another(path: Path) -> bool:
    """Whether another process holds the write lock of directory ``path``."""
    lock = path / _LOCK
    if not lock.exists():
        return False
    try:
        with open(lock, "a") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.flock(fh, fcntl.LOCK_UN)
        return False
    except OSError:
        return True


class ResultWriter:
    """Writes one result directory, checkpointing as it goes (see the module docstring).

    Construct it before any work: it validates ``out`` (InputValueError with one line naming the problem) and
    claims the directory it writes into (``out`` itself when new, else ``out.partial``).
    """

    def __init__(self, out, *, overwrite: bool = False):
        out = Path(out)
        self.out = out
        if out.exists() and not out.is_dir():
            raise InputValueError(f"--out {out}: exists and is not a directory")
        for d in (out, out.with_name(out.name + ".partial")):
            if d.is_dir() and _locked_by_another(d):
                raise InputValueError(f"--out {out}: another torchhand run is writing {d}; choose another directory")
        replacing = out.is_dir() and any(p.name != _LOCK for p in out.iterdir())
        if replacing and not _is_result_dir(out):
            raise InputValueError(f"--out {out}: exists, is not empty and is not a result directory; choose a new "
                                  f"directory (nothing was written)")
        if replacing and not overwrite:
            raise InputValueError(f"--out {out}: holds an earlier result; pass --overwrite to replace it (it is kept "
                                  f"whole until the new result is complete) or choose another directory")
        self.stage = out.with_name(out.name + ".partial") if replacing else out
        try:
            if self.stage != out and self.stage.exists():
                shutil.rmtree(self.stage)          # checkpoints of an earlier interrupted replacement of out
            self.stage.mkdir(parents=True, exist_ok=True)
            self._lock = open(self.stage / _LOCK, "a")        # held until this process ends (kill -9 included)
        except OSError as err:
            raise InputValueError(f"--out {out}: cannot write there ({err.strerror or err})") from None
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise InputValueError(f"--out {out}: another torchhand run is writing {self.stage}; choose another "
                                  f"directory") from None
        self.created = not replacing
        self.written = 0
        self.problem: SynthesisProblem | None = None

    def start(self, problem: SynthesisProblem, scene) -> None:
        """Write the scene, the hand models and a ``stats.json`` saying the run is partial."""
        self.begin(problem, scene, problem.hands)

    def begin(self, problem, scene, hands) -> None:
        """Any method's first files: ``scene`` (its hand tracks' models ``hands``, in the scene's hand order, as
        hand.xml and hand_<side>.xml), an emptied solutions/ and a ``stats.json`` saying the run is partial.
        ``problem`` is the run's own state (not None: the writer has started)."""
        self.problem = problem
        scene.export(self.stage / "scene", overwrite=True)
        for h, hand in enumerate(hands):
            name = "hand.xml" if h == 0 else f"hand_{scene.hands[h].side}.xml"
            write_hand_file(self.stage / name, hand, scene.hands[h])
        (self.stage / "solutions").mkdir(exist_ok=True)
        for old in (self.stage / "solutions").glob("sol_*.npz"):
            old.unlink()                           # only in a directory this run claimed: new, empty or .partial
        self._partial(scene.name, 0)

    def _partial(self, scene_name: str, count: int) -> None:
        _atomic_json(self.stage / "stats.json", {"format_version": FORMAT_VERSION, "complete": False,
                                                 "scene": scene_name, "solutions": count})

    def add(self, result: SynthesisResult, index: int) -> None:
        """Checkpoint solution ``index`` of ``result`` (its npz, then the partial stats)."""
        self.write_solution(index, solution_arrays(result, index), result.scene.name)

    def write_solution(self, index: int, arrays: dict, scene_name: str) -> None:
        """Checkpoint ``sol_<index>.npz`` with ``arrays`` (atomically), then the partial stats."""
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        _atomic_bytes(self.stage / "solutions" / f"sol_{index:03d}.npz", buf.getvalue())
        self.written = max(self.written, index + 1)
        self._partial(scene_name, self.written)

    def interrupted(self, result: SynthesisResult | None, scene_name: str) -> Path:
        """Leave the checkpoints readable after an interruption: ``stats.json`` says partial. Returns the
        directory that holds them."""
        if self.problem is not None:
            _atomic_json(self.stage / "stats.json", {"format_version": FORMAT_VERSION, "complete": False,
                                                     "interrupted": True, "scene": scene_name,
                                                     "solutions": self.written})
        return self.stage

    def abandon(self) -> None:
        """Remove what this writer created when nothing was written yet (bad input found after validation)."""
        if self.problem is None and self.stage.is_dir():
            self._unlock()
            if not any(self.stage.iterdir()):
                self.stage.rmdir()

    def _unlock(self) -> None:
        if not self._lock.closed:
            self._lock.close()
            (self.stage / _LOCK).unlink(missing_ok=True)

    def finish(self, result: SynthesisResult, *, threads: int | None = None) -> Path:
        """Write the final ``stats.json`` and, when replacing, swap the new directory in. Returns ``out``."""
        return self.complete(stats_dict(result, threads=threads))

    def complete(self, stats: dict) -> Path:
        """Write the final ``stats`` (``complete: true``), release the lock and, when replacing an earlier result,
        swap the new directory in. Returns ``out``."""
        _atomic_json(self.stage / "stats.json", stats)
        self._unlock()
        if self.stage != self.out:
            old = self.out.with_name(self.out.name + f".old-{os.getpid()}")
            os.replace(self.out, old)
            os.replace(self.stage, self.out)
            shutil.rmtree(old, ignore_errors=True)
        return self.out


def write_hand_file(path: Path, hand, track) -> None:
    """A result's hand file for the scene's hand track ``track`` and the synthesis' model ``hand``: for an MJCF hand the
    user's own file with a free joint (:mod:`torchhand.hand._mjcf_wrap`, from the float64 mounted model) when it reads
    back as the same model, otherwise (the built-in hand, a file with ``<include>``) torchhand's MJCF of ``hand``."""
    from ..hand._mjcf_wrap import _same_model, wrap_user_mjcf
    from ..hand.mjcf import load_mjcf
    from ..hand.mount import track_hand

    hand = hand.to("cpu", torch.float64)
    if track.model != "default":
        mounted = track_hand(track)
        if wrap_user_mjcf(track.model, mounted, path) is not None:
            try:
                if _same_model(load_mjcf(path), mounted):
                    return
            except TorchhandError:
                pass
        shutil.rmtree(path.with_name(path.stem + "_assets"), ignore_errors=True)
    _atomic_bytes(path, hand_to_mjcf(hand).encode())


def write_result(result: SynthesisResult, out, *, overwrite: bool = False, threads: int | None = None) -> Path:
    """Write the whole result directory at once (see :class:`ResultWriter`). Returns its path."""
    writer = ResultWriter(out, overwrite=overwrite)
    writer.start(result.problem, result.scene)
    for i in range(len(result.finals)):
        writer.add(result, i)
    return writer.finish(result, threads=threads)
