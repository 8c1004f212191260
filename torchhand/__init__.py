"""torchhand: physically plausible hand-motion synthesis on a batched PyTorch core.

See :mod:`torchhand.conventions` for units, frames and shape conventions.
"""

from __future__ import annotations

__version__ = "0.1.0"

from .errors import (  # noqa: F401
    FileFormatError,
    InputTypeError,
    InputValueError,
    MeshError,
    MissingFileError,
    ShapeError,
    TorchhandError,
    UnknownNameError,
)

_LAZY = {
    "HandModel": ".hand",
    "default_hand": ".hand",
    "SDFGrid": ".geometry.sdf",
    "RigidObject": ".geometry.objects",
    "load_object": ".geometry.objects",
    "Scene": ".scene",
    "load_scene": ".scene",
    "load_result": ".io.result",
    "Result": ".io.result",
    "synthesize": ".synthesis.pipeline",
    "SynthesisResult": ".synthesis.pipeline",
    "check_result": ".check",
    "CheckReport": ".check",
    "reproducible": "._numerics",       # the portable numeric profile (docs/synthesis.md)
    "NumericsProfile": "._numerics",
}


def __getattr__(name: str):
    # Lazy attributes keep `import torchhand` light (trimesh, scene parsing load on first use).
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'torchhand' has no attribute {name!r}")


__all__ = ["__version__", "TorchhandError", *_LAZY]
