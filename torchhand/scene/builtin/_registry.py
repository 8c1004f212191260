"""The registry of built-in scenes: zero-argument builders by name."""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

from ...errors import InputTypeError, UnknownNameError

if TYPE_CHECKING:  # pragma: no cover
    from .._model import Scene

__all__ = ["register_scene", "list_builtin_scenes", "builtin_scene", "builtin_scene_description"]

_REGISTRY: dict[str, tuple[Callable[[], "Scene"], str]] = {}


def register_scene(name: str, description: str) -> Callable[[Callable[[], "Scene"]], Callable[[], "Scene"]]:
    """Decorator registering a zero-argument scene builder under ``name`` (a later registration replaces it)."""
    if not isinstance(name, str) or not name:
        raise InputTypeError(f"name: expected a non-empty str, got {name!r}")

    def deco(fn: Callable[[], "Scene"]) -> Callable[[], "Scene"]:
        _REGISTRY[name] = (fn, description)
        return fn

    return deco


def list_builtin_scenes() -> list[str]:
    """Names of the built-in scenes, in registration order."""
    return list(_REGISTRY)


def _lookup(name: str) -> tuple[Callable[[], "Scene"], str]:
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise UnknownNameError(
            f"name: unknown built-in scene {name!r}; built-in scenes: {', '.join(_REGISTRY)}"
        ) from None


def builtin_scene(name: str) -> "Scene":
    """Build the built-in scene ``name`` (a fresh Scene each call); :class:`UnknownNameError` lists the names."""
    return _lookup(name)[0]()


def builtin_scene_description(name: str) -> str:
    """One-line description of the built-in scene ``name``."""
    return _lookup(name)[1]
