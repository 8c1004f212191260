"""Reading synthesis result directories and solution files (``docs/render.md`` lists the contract).

A result directory holds ``scene/`` (an exported scene), ``hand.xml`` (and ``hand_<side>.xml`` for a second hand),
``stats.json`` and ``solutions/sol_000.npz``, ``sol_001.npz``, ... Each solution file holds, for T frames, D finger
DOF, K hand-object contact slots and E object-environment contact slots:

    q (T, D) radians, joint_names (D,), root_pose (T, 4, 4) world, metres   (two hands: q_right, q_left,
        root_pose_right, root_pose_left; q / root_pose are the right hand's)
    object_pose (T, 4, 4), fps ()
    contact_mask (T, K) bool, contact_link (T, K) int (-1 padding), contact_link_name (N,) str,
    contact_point (T, K, 3) world metres, contact_normal (T, K, 3) into the object,
    contact_force (T, K, 3) newtons, force of the hand on the object
    env_contact_mask (T, E), env_contact_point (T, E, 3), env_contact_force (T, E, 3) newtons
    guiding (T, 5) bool, strategy (), friction ()

Everything is returned as NumPy (float64 / bool / int64): this module is the boundary the renderer and the plots
read. Missing optional arrays are left ``None``; a missing required array or a wrong shape is a
:class:`~torchhand.errors.FileFormatError` / :class:`~torchhand.errors.ShapeError` that names the file and the key.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from torchhand.errors import FileFormatError, InputValueError, MissingFileError, ShapeError

__all__ = ["HandSolution", "Solution", "ResultDir", "load_solution", "load_result_dir", "parse_solution_spec"]

SIDES = ("right", "left")


@dataclass(frozen=True, eq=False)
class HandSolution:
    """The finger motion of one hand in a solution.

    side: "right" or "left"
    q: finger joint angles, (T, D), radians, in ``joint_names`` order
    joint_names: (D,) str
    root_pose: wrist poses ``T_world_hand``, (T, 4, 4), world, metres
    guiding: guiding-finger flags, (T, 5) bool, or None
    """

    side: str
    q: np.ndarray
    joint_names: tuple
    root_pose: np.ndarray
    guiding: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Solution:
    """One synthesized (or reference) motion, NumPy arrays; see the module docstring for the fields."""

    path: Path
    hands: tuple[HandSolution, ...]
    fps: float
    object_pose: np.ndarray | None = None
    contact_mask: np.ndarray | None = None
    contact_link: np.ndarray | None = None
    contact_link_name: tuple = ()
    contact_point: np.ndarray | None = None
    contact_normal: np.ndarray | None = None
    contact_force: np.ndarray | None = None
    env_contact_mask: np.ndarray | None = None
    env_contact_point: np.ndarray | None = None
    env_contact_force: np.ndarray | None = None
    strategy: str = ""
    friction: float | None = None

    @property
    def T(self) -> int:
        """Number of frames."""
        return int(self.hands[0].q.shape[0])

    def hand(self, side: str) -> HandSolution | None:
        """The ``side`` hand's motion, or None."""
        return next((h for h in self.hands if h.side == side), None)

    def contact_side_link(self) -> tuple[np.ndarray, np.ndarray]:
        """Side index (into ``SIDES``, -1 padding) and link name index per contact slot, both (T, K) int64.

        Link names come from ``contact_link_name``; for two hands its entries are ``right/<link>`` or
        ``left/<link>``. Returns the side per slot and the index into :meth:`contact_link_names`.
        """
        if self.contact_link is None:
            raise FileFormatError(f"{self.path}: has no contact_link")
        names = self.contact_link_names()
        link = self.contact_link
        valid = (link >= 0) & (link < max(len(names), 1)) if names else (link >= 0)
        side = np.full(link.shape, -1, dtype=np.int64)
        default = SIDES.index(self.hands[0].side) if self.hands[0].side in SIDES else 0
        if self.contact_link_name:
            prefix = np.array([SIDES.index(n.split("/", 1)[0]) if "/" in n and n.split("/", 1)[0] in SIDES
                               else default for n in self.contact_link_name] or [default])
            side[valid] = prefix[np.clip(link[valid], 0, len(prefix) - 1)]
        else:
            side[valid] = default
        return side, np.where(valid, link, -1)

    def contact_link_names(self) -> tuple:
        """Link names of ``contact_link_name`` with any ``right/`` / ``left/`` prefix removed."""
        return tuple(n.split("/", 1)[1] if "/" in n else n for n in self.contact_link_name)


@dataclass(frozen=True, eq=False)
class ResultDir:
    """A synthesis result directory: the scene, the hand models per side, stats and the solution files."""

    path: Path
    scene: object  # torchhand.scene.Scene
    hand_models: dict = field(default_factory=dict)  # side -> HandModel
    stats: dict = field(default_factory=dict)
    solution_files: tuple = ()

    def solution(self, index: int) -> Solution:
        """Load solution ``index`` (position in ``solution_files``)."""
        if not 0 <= index < len(self.solution_files):
            raise InputValueError(f"solution {index}: {self.path} has {len(self.solution_files)} solutions "
                                  f"(0..{len(self.solution_files) - 1})")
        return load_solution(self.solution_files[index])


def parse_solution_spec(spec: str | None, count: int) -> list[int]:
    """``"0,1,2"`` / ``"all"`` / ``"1:4"`` / None (= [0]) -> solution indices, each checked against ``count``."""
    if count == 0:
        raise InputValueError("the result directory has no solutions (solutions/sol_*.npz)")
    if spec is None:
        return [0]
    spec = spec.strip()
    if spec == "all":
        return list(range(count))
    out: list[int] = []
    try:
        for part in spec.split(","):
            if ":" in part:
                a, b = part.split(":", 1)
                out.extend(range(int(a or 0), int(b) if b else count))
            else:
                out.append(int(part))
    except ValueError:
        raise InputValueError(f"--solutions: expected 'all' or indices like 0,1,2 or 0:4, got {spec!r}") from None
    bad = [i for i in out if not 0 <= i < count]
    if bad or not out:
        raise InputValueError(f"--solutions: indices {bad or spec} out of range; there are {count} solutions "
                              f"(0..{count - 1})")
    return out


def load_result_dir(path) -> ResultDir:
    """Open a result directory: load its scene, hand models and stats, list its solutions.

    Raises:
        MissingFileError: the directory, its ``scene/`` or its ``solutions/`` are missing.
        FileFormatError: ``stats.json`` or a hand file cannot be parsed.
    """
    from torchhand.hand import HandModel, default_hand
    from torchhand.scene import load_scene

    root = Path(path)
    if not root.is_dir():
        raise MissingFileError(f"result directory {root} does not exist (expected the output of "
                               f"`torchhand synthesize`)")
    if not (root / "scene").is_dir():
        raise MissingFileError(f"{root}: no scene/ directory; is this a result directory of `torchhand synthesize`?")
    scene = load_scene(root / "scene")
    stats: dict = {}
    if (root / "stats.json").exists():
        try:
            stats = json.loads((root / "stats.json").read_text())
        except (OSError, ValueError) as err:
            raise FileFormatError(f"{root / 'stats.json'}: not valid JSON ({err})") from None
        if not isinstance(stats, dict):
            raise FileFormatError(f"{root / 'stats.json'}: expected a JSON object, got {type(stats).__name__}")
    models = {}
    for k, track in enumerate(scene.hands):
        f = root / ("hand.xml" if k == 0 else f"hand_{track.side}.xml")
        models[track.side] = HandModel.from_mjcf(f) if f.exists() else default_hand(track.side, track.length)
    sol_dir = root / "solutions"
    if not sol_dir.is_dir():
        raise MissingFileError(f"{root}: no solutions/ directory")
    files = tuple(sorted(sol_dir.glob("sol_*.npz")))
    return ResultDir(path=root, scene=scene, hand_models=models, stats=stats, solution_files=files)


def _str(x) -> str:
    x = np.asarray(x)
    return str(x.item() if x.ndim == 0 else x.reshape(-1)[0]) if x.size else ""


def load_solution(path) -> Solution:
    """Read one solution npz (the contract in the module docstring).

    Raises:
        MissingFileError: the file does not exist.
        FileFormatError: not a readable npz, or a required key is missing.
        ShapeError: an array has the wrong shape (names the key, expected and actual shape).
    """
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"solution file {p} does not exist")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as err:
        raise FileFormatError(f"{p}: not a readable solution npz ({type(err).__name__}: {err})") from None

    def get(key, required=False):
        if key not in data:
            if required:
                raise FileFormatError(f"{p}: missing array {key!r} (keys: {', '.join(sorted(data)) or 'none'})")
            return None
        return data[key]

    def shaped(key, shape, dtype=np.float64, required=False):
        a = get(key, required)
        if a is None:
            return None
        if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
            desc = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
            raise ShapeError(f"{p}: {key}: expected shape {desc}, got {tuple(a.shape)}")
        try:
            return a.astype(dtype)
        except (TypeError, ValueError):
            raise FileFormatError(f"{p}: {key}: expected {np.dtype(dtype).name} values, got {a.dtype}") from None

    names = tuple(str(n) for n in np.asarray(get("joint_names", True)).reshape(-1))
    hands = []
    two = "q_left" in data or "root_pose_left" in data
    guiding_default = get("guiding")
    for side in (SIDES if two else (None,)):
        qk = "q" if side is None else f"q_{side}"
        rk = "root_pose" if side is None else f"root_pose_{side}"
        if side == "right" and qk not in data:
            qk, rk = "q", "root_pose"
        q = shaped(qk, (None, None), required=True)
        T = q.shape[0]
        root = shaped(rk, (T, 4, 4), required=True)
        jn = names
        if side is not None and f"joint_names_{side}" in data:
            jn = tuple(str(n) for n in np.asarray(data[f"joint_names_{side}"]).reshape(-1))
        if len(jn) != q.shape[1]:
            raise ShapeError(f"{p}: joint_names: expected {q.shape[1]} names (as {qk}), got {len(jn)}")
        g = get(f"guiding_{side}") if side is not None and f"guiding_{side}" in data else guiding_default
        hands.append(HandSolution(side=side or _str(data.get("side", "right")) or "right", q=q, joint_names=jn,
                                  root_pose=root, guiding=None if g is None else np.asarray(g, dtype=bool)))
    T = hands[0].q.shape[0]
    if T < 1:
        raise ShapeError(f"{p}: q: expected at least one frame, got shape {hands[0].q.shape}")
    for h in hands[1:]:
        if h.q.shape[0] != T:
            raise ShapeError(f"{p}: q_{h.side}: expected {T} frames, got {h.q.shape[0]}")
    fps = get("fps")
    fps = float(np.asarray(fps).reshape(-1)[0]) if fps is not None and np.asarray(fps).size else 30.0
    if not np.isfinite(fps) or fps <= 0:
        raise FileFormatError(f"{p}: fps: expected a positive number, got {fps}")
    K = data["contact_mask"].shape[1] if "contact_mask" in data and data["contact_mask"].ndim == 2 else None
    E = data["env_contact_mask"].shape[1] if "env_contact_mask" in data and data["env_contact_mask"].ndim == 2 \
        else None
    friction = get("friction")
    link_names = get("contact_link_name")
    sol = Solution(
        path=p, hands=tuple(hands), fps=fps,
        object_pose=shaped("object_pose", (T, 4, 4)),
        contact_mask=shaped("contact_mask", (T, None), bool),
        contact_link=shaped("contact_link", (T, K), np.int64),
        contact_link_name=() if link_names is None else tuple(str(n) for n in np.asarray(link_names).reshape(-1)),
        contact_point=shaped("contact_point", (T, K, 3)),
        contact_normal=shaped("contact_normal", (T, K, 3)),
        contact_force=shaped("contact_force", (T, K, 3)),
        env_contact_mask=shaped("env_contact_mask", (T, None), bool),
        env_contact_point=shaped("env_contact_point", (T, E, 3)),
        env_contact_force=shaped("env_contact_force", (T, E, 3)),
        strategy=_str(get("strategy")) if get("strategy") is not None else "",
        friction=float(np.asarray(friction).reshape(-1)[0]) if friction is not None and np.asarray(friction).size
        else None,
    )
    for key in ("q", "root_pose", "object_pose", "contact_point", "contact_force", "env_contact_point",
                "env_contact_force"):
        a = getattr(sol, key, None) if key not in ("q", "root_pose") else None
        arrays = [getattr(h, key) for h in sol.hands] if key in ("q", "root_pose") else [a]
        for arr in arrays:
            if arr is not None and not np.isfinite(arr).all():
                raise FileFormatError(f"{p}: {key}: contains NaN or inf")
    return sol
