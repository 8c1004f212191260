"""Reading result directories: the one reader of the format in ``docs/result_format.md``.

A result directory holds ``scene/``, ``hand.xml`` (and ``hand_<side>.xml`` for a second hand), ``stats.json`` and
``solutions/sol_000.npz``, ``sol_001.npz``, ... :func:`load_result` opens a directory as a :class:`Result`;
:func:`load_solution` reads one solution file as a :class:`Solution`. ``docs/result_format.md`` lists every key with
its shape, dtype, unit and frame; this module checks them and names the file and the key when one is missing or
wrong.

Everything is returned as NumPy (float64 / bool / int64): this module is the boundary that render, plot and the
checker read, and it imports neither torch nor the synthesis (the scene and hand loaders are imported by
:func:`load_result` when it runs). Shapes use T frames, D finger joints per hand, K hand-object contact slots, E
object-environment contact slots, F fingers, N contact link names. Conventions (see :mod:`torchhand.conventions`):
metres, seconds, radians, newtons, world frame, column-vector 4x4 transforms ``T_world_frame``, contact normals
pointing into the object.

Versions: files written before versioning have no ``format_version`` and read as version 0, with the same keys as
version 1. A ``format_version`` above :data:`FORMAT_VERSION` is a :class:`~torchhand.errors.FileFormatError`
(the file comes from a newer torchhand).
"""

from __future__ import annotations

import json
import re
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import FileFormatError, InputValueError, MissingFileError, ShapeError, UnknownNameError

if TYPE_CHECKING:
    from ..scene import Scene

__all__ = [
    "FORMAT_VERSION",
    "SIDES",
    "HandSolution",
    "Solution",
    "Result",
    "load_result",
    "load_solution",
    "solution_from_arrays",
    "parse_solution_spec",
]

FORMAT_VERSION = 1
"""Version of the result format this module reads and ``torchhand synthesize`` writes: ``format_version`` in
``stats.json`` (int) and in every ``sol_XXX.npz`` (0-d int array). 0 = written before versioning."""

SIDES = ("right", "left")
"""Hand sides; :meth:`Solution.contact_side_link` returns indices into this tuple."""

_SOL_NAME = re.compile(r"^sol_(\d+)\.npz$")


@dataclass(frozen=True, eq=False)
class HandSolution:
    """The finger motion of one hand in a solution.

    side: "right" or "left"
    q: finger joint angles, (T, D), float64, radians, in ``joint_names`` order
    joint_names: (D,) str
    root_pose: wrist poses ``T_world_hand``, (T, 4, 4), float64, world, metres
    guiding: guiding-finger flags, (T, F) bool, or None when the file has none
    root_pose_captured: the wrist track as captured, (T, 4, 4), when the method moved the wrist from it (optional
        key ``root_pose_captured``), else None
    """

    side: str
    q: np.ndarray
    joint_names: tuple
    root_pose: np.ndarray
    guiding: np.ndarray | None = None
    root_pose_captured: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Solution:
    """One solution file ``sol_XXX.npz`` (``docs/result_format.md``), NumPy.

    path: the file
    index: XXX of ``sol_XXX.npz`` (-1 for a file named otherwise)
    hands: one :class:`HandSolution` per hand, in the scene's hand order
    fps: frames per second
    object_pose: ``T_world_object``, (T, 4, 4), float64, metres
    contact_mask: (T, K) bool, the slot holds a hand-object contact
    contact_link: (T, K) int64, index into ``contact_link_name``, -1 in padding slots
    contact_link_name: (N,) str, link names; ``right/<link>`` / ``left/<link>`` with two hands
    contact_point: (T, K, 3) float64, world, metres, on the object surface
    contact_normal: (T, K, 3) float64, unit, into the object (the synthesis' own normal)
    contact_force: (T, K, 3) float64, newtons, force of the hand on the object
    contact_sliding: (T, K) bool, the hand point slides over the object (force on the cone boundary)
    env_contact_mask: (T, E) bool; env_contact_point: (T, E, 3) world, metres; env_contact_force: (T, E, 3)
        newtons, force of the environment on the object
    strategy: the strategy preference of the run ("" when the file has none)
    friction: the hand-object friction coefficient the writer used, or None when the file has none
    reconstructed: ``q`` is the smoothed motion (False: the searched poses, kept unsmoothed)
    format_version: the file's ``format_version``, 0 for files written before versioning
    object_mass: the object's mass this solution was made with, kg (optional key ``variant_mass``: rollouts of
        other masses in one directory), or None when the file has none (the scene's mass applies)
    object_pose_captured: the object track as captured, (T, 4, 4), when the method moved the object from it
        within capture noise (optional key ``object_pose_captured``), else None
    """

    path: Path
    index: int
    hands: tuple[HandSolution, ...]
    fps: float
    object_pose: np.ndarray
    contact_mask: np.ndarray
    contact_link: np.ndarray
    contact_link_name: tuple
    contact_point: np.ndarray
    contact_normal: np.ndarray
    contact_force: np.ndarray
    contact_sliding: np.ndarray
    env_contact_mask: np.ndarray
    env_contact_point: np.ndarray
    env_contact_force: np.ndarray
    strategy: str
    friction: float | None
    reconstructed: bool
    format_version: int
    object_mass: float | None = None
    object_pose_captured: np.ndarray | None = None

    @property
    def T(self) -> int:
        """Number of frames."""
        return int(self.object_pose.shape[0])

    @property
    def q(self) -> np.ndarray:
        """The only hand's finger joint angles, (T, D), radians; with two hands use ``.hand(side).q``."""
        return self._only_hand("q").q

    @property
    def root_pose(self) -> np.ndarray:
        """The only hand's wrist poses, (T, 4, 4); with two hands use ``.hand(side).root_pose``."""
        return self._only_hand("root_pose").root_pose

    def _only_hand(self, attr: str) -> HandSolution:
        if len(self.hands) != 1:
            sides = ", ".join(h.side for h in self.hands)
            raise InputValueError(f"{self.path}: {attr}: the solution has {len(self.hands)} hands ({sides}); use "
                                  + " or ".join(f'.hand("{h.side}").{attr}' for h in self.hands))
        return self.hands[0]

    def hand(self, side: str) -> HandSolution:
        """The ``side`` hand's motion. Raises UnknownNameError naming the sides present."""
        for h in self.hands:
            if h.side == side:
                return h
        raise UnknownNameError(f"{self.path}: no {side!r} hand; the solution has "
                               f"{', '.join(repr(h.side) for h in self.hands)}")

    def contact_side_link(self) -> tuple[np.ndarray, np.ndarray]:
        """Side index (into :data:`SIDES`, -1 in padding) and link name index (into :meth:`contact_link_names`,
        -1 in padding) per contact slot, both (T, K) int64. The side comes from the ``right/`` / ``left/`` prefix
        of ``contact_link_name``; unprefixed names belong to the first hand."""
        names = self.contact_link_name
        link = self.contact_link
        valid = (link >= 0) & (link < len(names))
        default = SIDES.index(self.hands[0].side) if self.hands[0].side in SIDES else 0
        prefix = np.array([SIDES.index(n.split("/", 1)[0]) if n.split("/", 1)[0] in SIDES and "/" in n
                           else default for n in names] or [default], dtype=np.int64)
        side = np.where(valid, prefix[np.clip(link, 0, len(prefix) - 1)], -1)
        return side, np.where(valid, link, -1)

    def contact_link_names(self) -> tuple:
        """Link names of ``contact_link_name`` with any ``right/`` / ``left/`` prefix removed."""
        return tuple(n.split("/", 1)[1] if "/" in n else n for n in self.contact_link_name)


@dataclass(frozen=True, eq=False)
class Result:
    """A result directory (``docs/result_format.md``).

    path: the directory
    scene: the scene of ``scene/`` (:class:`torchhand.scene.Scene`)
    hand_models: side -> :class:`~torchhand.hand.HandModel`, from ``hand.xml`` (first hand) / ``hand_<side>.xml``
        (second hand); the default hand at the track's length when the file is absent
    stats: the object of ``stats.json`` ({} when absent)
    solution_files: the ``solutions/sol_XXX.npz`` files, in the order of XXX
    format_version: ``stats["format_version"]``, 0 when absent
    complete: ``stats["complete"]``: False while a run is writing or after it was interrupted (the solutions
        present are whole, more may be missing); True when absent
    """

    path: Path
    scene: Scene
    hand_models: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    solution_files: tuple = ()
    format_version: int = 0
    complete: bool = True

    @cached_property
    def solutions(self) -> tuple[Solution, ...]:
        """Every solution, loaded on first access, in the order of ``solution_files``."""
        return tuple(self.solution(i) for i in range(len(self.solution_files)))

    def solution(self, i: int) -> Solution:
        """Solution ``i`` (position in ``solution_files``), its hands in the scene's hand order."""
        if not 0 <= i < len(self.solution_files):
            raise InputValueError(f"solution {i}: {self.path} has {len(self.solution_files)} solutions"
                                  + (f" (0..{len(self.solution_files) - 1})" if self.solution_files else ""))
        return _in_scene_order(load_solution(self.solution_files[i]), self.scene)


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


# ---------------------------------------------------------------------------------------------------------------
# Result directories


def _check_version(v, where: str) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
        raise FileFormatError(f"{where}: format_version: expected a non-negative integer, got {v!r}")
    if v > FORMAT_VERSION:
        raise FileFormatError(f"{where}: format_version {int(v)} is newer than this torchhand reads "
                              f"(up to {FORMAT_VERSION}); update torchhand")
    return int(v)


def _read_stats(root: Path) -> dict:
    f = root / "stats.json"
    if not f.exists():
        return {}
    try:
        stats = json.loads(f.read_text())
    except (OSError, ValueError) as err:
        raise FileFormatError(f"{f}: not valid JSON ({err})") from None
    if not isinstance(stats, dict):
        raise FileFormatError(f"{f}: expected a JSON object, got {type(stats).__name__}")
    return stats


def load_result(path) -> Result:
    """Open a result directory: its scene, hand models and stats, and the list of its solution files.

    Solutions are read on access (:meth:`Result.solution`, :attr:`Result.solutions`).

    Raises:
        MissingFileError: the directory, its ``scene/`` or (for a complete run) its ``solutions/`` are missing.
        FileFormatError: ``stats.json`` or a hand file cannot be parsed, a ``stats.json`` key has the wrong type,
            or ``format_version`` is newer than :data:`FORMAT_VERSION`.
    """
    from ..hand import HandModel, default_hand
    from ..scene import load_scene

    root = Path(path)
    if not root.is_dir():
        raise MissingFileError(f"result directory {root} does not exist (expected the output of "
                               f"`torchhand synthesize`)")
    if not (root / "scene").is_dir():
        raise MissingFileError(f"{root}: no scene/ directory; is this a result directory of `torchhand synthesize`?")
    stats = _read_stats(root)
    version = _check_version(stats.get("format_version", 0), str(root / "stats.json"))
    complete = stats.get("complete", True)
    if not isinstance(complete, bool):
        raise FileFormatError(f"{root / 'stats.json'}: complete: expected true or false, got {complete!r}")
    scene = load_scene(root / "scene")
    models = {}
    for k, track in enumerate(scene.hands):
        f = root / ("hand.xml" if k == 0 else f"hand_{track.side}.xml")
        models[track.side] = HandModel.from_mjcf(f) if f.exists() else default_hand(track.side, track.length)
    sol_dir = root / "solutions"
    if sol_dir.is_dir():
        files = tuple(sorted((f for f in sol_dir.glob("sol_*.npz") if _SOL_NAME.match(f.name)),
                             key=lambda f: int(_SOL_NAME.match(f.name).group(1))))
    elif complete:
        raise MissingFileError(f"{root}: no solutions/ directory")
    else:
        files = ()
    return Result(path=root, scene=scene, hand_models=models, stats=stats, solution_files=files,
                  format_version=version, complete=complete)


def _in_scene_order(sol: Solution, scene) -> Solution:
    """``sol`` with its hands in the scene's order (a lone hand takes the scene's side)."""
    import dataclasses

    sides = [t.side for t in scene.hands]
    if sol.T != scene.T:
        raise ShapeError(f"{sol.path}: object_pose: expected {scene.T} frames as the scene, got {sol.T}")
    if len(sol.hands) != len(sides):
        raise ShapeError(f"{sol.path}: expected {len(sides)} hand(s) ({', '.join(sides)}) as the scene, "
                         f"got {len(sol.hands)}")
    if len(sides) == 1:
        if sol.hands[0].side == sides[0]:
            return sol
        return dataclasses.replace(sol, hands=(dataclasses.replace(sol.hands[0], side=sides[0]),))
    have = {h.side: h for h in sol.hands}
    if set(have) != set(sides):
        raise FileFormatError(f"{sol.path}: expected hands {', '.join(sides)} as the scene, got "
                              f"{', '.join(have)}")
    return dataclasses.replace(sol, hands=tuple(have[s] for s in sides))


# ---------------------------------------------------------------------------------------------------------------
# Solution files


class _Npz:
    """The arrays of one npz with checks that name the file and the key."""

    def __init__(self, path: Path, data: dict, version: int):
        self.path, self.data, self.version = path, data, version

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str) -> np.ndarray:
        if key not in self.data:
            old = " (a file written before format_version 1; write it again with this torchhand)" \
                if self.version == 0 else ""
            raise FileFormatError(f"{self.path}: missing array {key!r}{old} "
                                  f"(keys: {', '.join(sorted(self.data)) or 'none'})")
        return self.data[key]

    def array(self, key: str, shape: tuple, kind: str) -> np.ndarray:
        """``key`` with ``shape`` (None = any size) and dtype kind "f" (float64, finite), "b" (bool) or "i"
        (int64)."""
        a = self.get(key)
        if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
            desc = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
            raise ShapeError(f"{self.path}: {key}: expected shape {desc}, got {tuple(a.shape)}")
        ok = {"f": "fiu", "b": "b", "i": "iu"}[kind]
        if a.dtype.kind not in ok:
            want = {"f": "float", "b": "bool", "i": "integer"}[kind]
            raise FileFormatError(f"{self.path}: {key}: expected {want} values, got dtype {a.dtype}")
        if kind == "f":
            a = a.astype(np.float64)
            if not np.isfinite(a).all():
                raise FileFormatError(f"{self.path}: {key}: contains NaN or inf")
            return a
        return a.astype(bool if kind == "b" else np.int64)

    def names(self, key: str) -> tuple:
        a = self.get(key)
        if a.ndim != 1 or a.dtype.kind not in "US":
            raise FileFormatError(f"{self.path}: {key}: expected a (N,) array of strings, got shape "
                                  f"{tuple(a.shape)} dtype {a.dtype}")
        return tuple(str(n) for n in a)

    def scalar(self, key: str, kinds: str) -> object:
        a = self.get(key)
        if a.shape != () or a.dtype.kind not in kinds:
            raise FileFormatError(f"{self.path}: {key}: expected a 0-d array of kind {kinds!r}, got shape "
                                  f"{tuple(a.shape)} dtype {a.dtype}")
        return a.item()


def _read_npz(p: Path) -> dict:
    if not p.is_file():
        raise MissingFileError(f"solution file {p} does not exist")
    try:
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as err:
        raise FileFormatError(f"{p}: not a readable solution npz ({type(err).__name__}: {err})") from None


def _hands(z: _Npz) -> list[HandSolution]:
    """The hands of a file: ``q_<side>`` ... in the order the file stores them, else one hand in ``q``."""
    sides = [k[2:] for k in z.data if k.startswith("q_") and k[2:] in SIDES]
    names = z.names("joint_names")
    guiding = z.data.get("guiding")
    hands = []
    for side in sides or [None]:
        sfx = "" if side is None else f"_{side}"
        q = z.array(f"q{sfx}", (None, None), "f")
        T = q.shape[0]
        if T < 1:
            raise ShapeError(f"{z.path}: q{sfx}: expected at least one frame, got shape {q.shape}")
        root = z.array(f"root_pose{sfx}", (T, 4, 4), "f")
        jn = z.names(f"joint_names{sfx}") if side is not None and z.has(f"joint_names{sfx}") else names
        if len(jn) != q.shape[1]:
            key = f"joint_names{sfx}" if side is not None and z.has(f"joint_names{sfx}") else "joint_names"
            raise ShapeError(f"{z.path}: {key}: expected {q.shape[1]} names (as q{sfx}), got {len(jn)}")
        g = None
        if z.has(f"guiding{sfx}") or guiding is not None:
            g = z.array(f"guiding{sfx}" if z.has(f"guiding{sfx}") else "guiding", (T, None), "b")
        hand_side = side
        if side is None:
            hand_side = str(z.scalar("side", "US")) if z.has("side") else "right"
            if hand_side not in SIDES:
                raise FileFormatError(f"{z.path}: side: expected 'right' or 'left', got {hand_side!r}")
        captured = None
        if z.has(f"root_pose_captured{sfx}") or (side is None and z.has("root_pose_captured")):
            captured = z.array(f"root_pose_captured{sfx}", (T, 4, 4), "f")
        hands.append(HandSolution(side=hand_side, q=q, joint_names=jn, root_pose=root, guiding=g,
                                  root_pose_captured=captured))
    return hands


def load_solution(path) -> Solution:
    """Read one solution file (``docs/result_format.md``). Its hands come in the order the file stores them; read
    through :meth:`Result.solution` to get them in the scene's order.

    Raises:
        MissingFileError: the file does not exist.
        FileFormatError: not a readable npz, a key is missing, has the wrong dtype or holds NaN / inf, a contact
            link index is out of range, or ``format_version`` is newer than :data:`FORMAT_VERSION`.
        ShapeError: an array has the wrong shape (names the key, the expected and the actual shape).
    """
    p = Path(path)
    return solution_from_arrays(_read_npz(p), p)


def solution_from_arrays(data: dict, path) -> Solution:
    """A :class:`Solution` from the arrays of a solution file (key -> NumPy array, as ``np.load`` gives them), with
    the checks of :func:`load_solution`; ``path`` names the file in errors and gives :attr:`Solution.index`."""
    p = Path(path)
    data = {k: np.asarray(v) for k, v in data.items()}
    version = 0
    if "format_version" in data:
        v = data["format_version"]
        if v.shape != () or v.dtype.kind not in "iu":
            raise FileFormatError(f"{p}: format_version: expected a 0-d integer array, got shape {tuple(v.shape)} "
                                  f"dtype {v.dtype}")
        version = _check_version(int(v), str(p))
    z = _Npz(p, data, version)
    hands = _hands(z)
    T = hands[0].q.shape[0]
    for h in hands[1:]:
        if h.q.shape[0] != T:
            raise ShapeError(f"{p}: q_{h.side}: expected {T} frames (as q_{hands[0].side}), got {h.q.shape[0]}")
    fps = float(z.scalar("fps", "fiu"))
    if not np.isfinite(fps) or fps <= 0:
        raise FileFormatError(f"{p}: fps: expected a positive number, got {fps}")
    mask = z.array("contact_mask", (T, None), "b")
    K = mask.shape[1]
    link = z.array("contact_link", (T, K), "i")
    link_names = z.names("contact_link_name")
    bad = mask & ((link < 0) | (link >= len(link_names)))
    if bad.any():
        t, k = (int(i) for i in np.argwhere(bad)[0])
        raise FileFormatError(f"{p}: contact_link: expected indices in [0, {len(link_names)}) where contact_mask is "
                              f"set, got {int(link[t, k])} at frame {t}, slot {k}")
    env_mask = z.array("env_contact_mask", (T, None), "b")
    E = env_mask.shape[1]
    friction = float(z.scalar("friction", "fiu")) if z.has("friction") else None
    if friction is not None and not (np.isfinite(friction) and friction >= 0):
        raise FileFormatError(f"{p}: friction: expected a non-negative number, got {friction}")
    mass = float(z.scalar("variant_mass", "fiu")) if z.has("variant_mass") else None
    if mass is not None and not (np.isfinite(mass) and mass > 0):
        raise FileFormatError(f"{p}: variant_mass: expected a positive number of kg, got {mass}")
    m = _SOL_NAME.match(p.name)
    return Solution(
        path=p, index=int(m.group(1)) if m else -1, hands=tuple(hands), fps=fps,
        object_pose=z.array("object_pose", (T, 4, 4), "f"),
        contact_mask=mask, contact_link=np.where(mask, link, -1), contact_link_name=link_names,
        contact_point=z.array("contact_point", (T, K, 3), "f"),
        contact_normal=z.array("contact_normal", (T, K, 3), "f"),
        contact_force=z.array("contact_force", (T, K, 3), "f"),
        contact_sliding=z.array("contact_sliding", (T, K), "b") & mask,
        env_contact_mask=env_mask,
        env_contact_point=z.array("env_contact_point", (T, E, 3), "f"),
        env_contact_force=z.array("env_contact_force", (T, E, 3), "f"),
        strategy=str(z.scalar("strategy", "US")) if z.has("strategy") else "",
        friction=friction,
        reconstructed=bool(z.scalar("reconstructed", "biu")),
        format_version=version,
        object_mass=mass,
        object_pose_captured=z.array("object_pose_captured", (T, 4, 4), "f") if z.has("object_pose_captured")
        else None,
    )
