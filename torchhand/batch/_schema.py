"""The schema of a batch manifest (:mod:`torchhand.batch.manifest`): the methods, the lists each expands, each
method's options (flag, type, default, range), and the validation of one ``[[jobs]]`` table merged over
``[defaults]`` (:func:`_table`), every error naming the table and the key."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

from ..errors import InputValueError, UnknownNameError

__all__ = ["METHODS", "FUTURE_METHODS", "OPTIONS", "MANIPULATE_OPTIONS", "CAPTURE_OPTIONS", "METHOD_OPTIONS",
           "METHOD_LISTS"]

METHODS = ("synthesize", "manipulate", "capture")
"""Methods a batch runs (``capture`` is ``torchhand capture resynthesize``)."""

FUTURE_METHODS = {
    "splice": "run `torchhand splice --body B --hand H --out DIR` for each pair",
}
"""Methods of torchhand that batch manifests do not run, with what to do instead."""


@dataclass(frozen=True)
class _Option:
    flag: str                 # the command's flag
    kind: str                 # "int", "float", "floats" (a list, passed comma-separated), "str", "bool", "frames"
    default: object           # the flag's default (None: the flag is left out)
    low: float | None = None  # least value (ints and floats)
    strict: bool = False      # value must exceed ``low``
    choices: tuple = ()
    high: float | None = None  # greatest value (inclusive)


OPTIONS = {
    "solutions": _Option("--solutions", "int", 10, 1),
    "max_nodes": _Option("--max-nodes", "int", 60000, 0),
    "time_budget": _Option("--time-budget", "float", None, 0, strict=True),
    "epsilon": _Option("--epsilon", "float", 10.0, 0, strict=True),
    "strategy": _Option("--strategy", "str", "mixed", choices=("static", "sliding", "relocating", "mixed", "gait")),
    "frames": _Option("--frames", "frames", None),
    "slide_speed": _Option("--slide-speed", "float", None, 0, strict=True),
    "smooth": _Option("--smooth", "float", 0.0, 0),
    "max_joint_speed": _Option("--max-joint-speed", "float", 8.0, 0, strict=True),
    "keep_unsmoothed": _Option("--keep-unsmoothed", "bool", False),
    "no_reconstruct": _Option("--no-reconstruct", "bool", False),
    "trees": _Option("--trees", "int", 16, 1),
    "candidates": _Option("--candidates", "int", 16, 1),
    "dtype": _Option("--dtype", "str", "float32", choices=("float32", "float64")),
}
"""Options of a ``synthesize`` job: manifest key -> flag, type, default (the flag's own default; a test holds the
two together), range. ``seed`` is not an option: seeds are listed as ``seeds = [...]``."""

MANIPULATE_OPTIONS = {
    "window": _Option("--window", "int", 6, 1),
    "max_force": _Option("--max-force", "float", 30.0, 0, strict=True),
    "frames": _Option("--frames", "frames", None),
    "no_objective": _Option("--no-objective", "bool", False),
    "dynamics": _Option("--dynamics", "str", "quasi-static", choices=("quasi-static", "full")),
    "sliding": _Option("--sliding", "bool", False),
    "max_iters": _Option("--max-iters", "int", 30, 1),
}
"""Options of a ``manipulate`` job (``torchhand manipulate``'s flags and defaults; a test holds them together)."""

CAPTURE_OPTIONS = {
    "dt": _Option("--dt", "float", None, 0, strict=True),
    "mass": _Option("--mass", "floats", None, 0, strict=True),
    "compliance_scale": _Option("--compliance-scale", "floats", (1.0,), 0, strict=True),
    "friction": _Option("--friction", "floats", None, 0),
    "grip": _Option("--grip", "str", "none", choices=("none", "delayed", "imminent")),
    "slip_ratio": _Option("--slip-ratio", "float", 0.9, 0, strict=True),
    "min_force": _Option("--min-force", "float", 0.2, 0),
    "tighten": _Option("--tighten", "float", 0.95, 0, strict=True, high=1.0),
    "grip_floor": _Option("--grip-floor", "float", 0.2, 0, strict=True, high=1.0),
    "grip_delay": _Option("--grip-delay", "float", 0.1, 0),
    "pyramid_m": _Option("--pyramid-m", "int", 4, 1),
    "solver": _Option("--solver", "str", None, choices=("lemke", "pgs", "auto")),
    "settle_steps": _Option("--settle-steps", "int", 0, 0),
    "close_open": _Option("--close-open", "bool", False),
    "dtype": _Option("--dtype", "str", "float64", choices=("float64", "float32")),
    "object_contacts": _Option("--object-contacts", "str", "mesh", choices=("mesh", "sdf")),
    "sdf_voxel": _Option("--sdf-voxel", "float", 0.001, 0, strict=True),
    "finger_friction": _Option("--finger-friction", "float", 0.0, 0),
    "reach": _Option("--reach", "bool", False),
    "reach_rate": _Option("--reach-rate", "float", 0.5, 0),
    "reach_limit": _Option("--reach-limit", "float", 0.25, 0),
}
"""Options of a ``capture`` job (``torchhand capture resynthesize``'s flags and defaults; a test holds them
together). ``mass``, ``compliance_scale`` and ``friction`` are lists (one rollout per combination) or one number."""

METHOD_OPTIONS = {"synthesize": OPTIONS, "manipulate": MANIPULATE_OPTIONS, "capture": CAPTURE_OPTIONS}
"""Method -> its options."""

METHOD_LISTS = {"synthesize": ("scenes", "seeds", "hands"), "manipulate": ("scenes", "grasps"),
                "capture": ("interactions", "scenes")}
"""Method -> the lists its jobs expand (as a product, in this order)."""

_NOT_FOR = {"seeds": "its result does not depend on a seed",
            "hands": {"manipulate": "the hand is the grasp's", "capture": "the hand is the scene's"},
            "grasps": "only manipulate jobs have grasps", "interactions": "only capture jobs have interactions"}
_ALL_KEYS = ("method",) + tuple(dict.fromkeys(k for m in METHODS for k in METHOD_LISTS[m] + tuple(METHOD_OPTIONS[m])))
_SIDES = ("right", "left")


@dataclass(frozen=True)
class _Table:
    """One ``[[jobs]]`` table, validated: its ``method``, its keys merged over the defaults that apply to the
    method (``merged``, key -> TOML value), and every option of the method with its default filled in
    (``options``, in :data:`METHOD_OPTIONS` order)."""

    method: str
    merged: dict
    options: tuple[tuple[str, object], ...]


def _table(defaults: dict, table: dict, where: str) -> _Table:
    """``table`` checked (method, keys, option values) and merged over ``defaults``."""
    method = table.get("method", defaults.get("method", "synthesize"))
    _check_method(method, where)
    _check_keys(table, where, method)
    merged = {k: v for k, v in defaults.items() if k == "method" or k in METHOD_LISTS[method]
              or k in METHOD_OPTIONS[method]}
    merged.update(table)
    return _Table(method=method, merged=merged, options=_options(merged, METHOD_OPTIONS[method], where))


def _check_keys(table: dict, where: str, method: str | None) -> None:
    """Every key known; in a [[jobs]] table (``method`` given), every key one of that method's."""
    for key in table:
        if method is not None and key in METHOD_LISTS[method] + ("method",) + tuple(METHOD_OPTIONS[method]):
            continue
        if method is None and key in _ALL_KEYS:
            continue
        if key in _ALL_KEYS:
            why = _NOT_FOR.get(key, "")
            why = why.get(method, "") if isinstance(why, dict) else why
            owners = [m for m in METHODS if key in METHOD_LISTS[m] or key in METHOD_OPTIONS[m]]
            raise InputValueError(f"{where}: key '{key}' does not apply to method '{method}'"
                                  f"{f' ({why})' if why else ''}; it is a key of {', '.join(owners)}; keys of "
                                  f"{method}: {', '.join(METHOD_LISTS[method] + tuple(METHOD_OPTIONS[method]))}")
        known = (METHOD_LISTS[method] + tuple(METHOD_OPTIONS[method])) if method else _ALL_KEYS[1:]
        hint = "; list seeds as seeds = [0, 1]" if key == "seed" else \
            "; list grasps as grasps = [\"g.npz\"]" if key == "grasp" else \
            "; list interactions as interactions = [\"interaction.npz\"]" if key == "interaction" else \
            "; --threads and --device are options of `torchhand batch`" if key in ("threads", "device") else \
            f"; known: method, {', '.join(known)}"
        raise UnknownNameError(f"{where}: unknown key '{key}'{hint}")


def _check_method(method, where: str) -> None:
    if method in METHODS:
        return
    if method in FUTURE_METHODS:
        raise InputValueError(f"{where}: method '{method}' is not available in batch manifests "
                              f"({FUTURE_METHODS[method]}); available: {', '.join(METHODS)}")
    raise UnknownNameError(f"{where}: unknown method {method!r}; available: {', '.join(METHODS)}")


def _options(merged: dict, specs: dict, where: str) -> tuple[tuple[str, object], ...]:
    out = []
    for name, spec in specs.items():
        value = spec.default
        if name in merged:
            value = _option_value(name, spec, merged[name], where)
        out.append((name, value))
    return tuple(out)


def _option_value(name: str, spec: _Option, value, where: str):
    bad = lambda what: InputValueError(f"{where}: {name}: expected {what}, got {value!r}")  # noqa: E731
    if spec.kind == "bool":
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if spec.kind in ("str", "frames"):
        if not isinstance(value, str):
            raise bad("a string")
        if spec.choices and value not in spec.choices:
            raise bad(f"one of {', '.join(spec.choices)}")
        if spec.kind == "frames":
            m = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*", value)
            if not m or int(m[1]) >= int(m[2]):
                raise bad('"START:STOP" with integers 0 <= START < STOP')
            return f"{int(m[1])}:{int(m[2])}"
        return value
    if spec.kind == "floats":
        values = value if isinstance(value, list) else [value]
        if not values:
            raise bad("a number or a non-empty list of numbers")
        return tuple(_number(name, dataclasses.replace(spec, kind="float"), v, where, "a number or a list of "
                                                                                            "numbers") for v in values)
    return _number(name, spec, value, where)


def _number(name: str, spec: _Option, value, where: str, what: str | None = None):
    bad = lambda text: InputValueError(f"{where}: {name}: expected {text}, got {value!r}")  # noqa: E731
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (spec.kind == "int" and
                                                                           not isinstance(value, int)):
        raise bad(what or ("an integer" if spec.kind == "int" else "a number"))
    value = int(value) if spec.kind == "int" else float(value)
    if value != value or spec.low is not None and (value <= spec.low if spec.strict else value < spec.low) or \
            spec.high is not None and value > spec.high:
        lo = f"{'>' if spec.strict else '>='} {spec.low:g}" if spec.low is not None else ""
        raise bad(f"a number {lo}" + (f" and <= {spec.high:g}" if spec.high is not None else ""))
    return value


def _list(merged: dict, key: str, kind: type, where: str, default):
    value = merged.get(key, default)
    if value is None:
        raise InputValueError(f"{where}: no '{key}' (a list, here or in [defaults])")
    if not isinstance(value, list) or not value or not all(isinstance(v, kind) and not isinstance(v, bool)
                                                           for v in value):
        raise InputValueError(f"{where}: {key}: expected a non-empty list of "
                              f"{'integers' if kind is int else 'strings'}, got {value!r}")
    return value
