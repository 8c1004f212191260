"""torchhand: physically plausible hand-motion synthesis on a batched PyTorch core.

What users import, in one place (each name is loaded on first use, so ``import torchhand`` stays light):

=====================  ==================================================================================
hand model             :class:`HandModel`, :func:`default_hand` (docs/hand_model.md)
objects and geometry   :class:`RigidObject`, :func:`load_object`, :class:`SDFGrid`
scenes                 :class:`Scene`, :func:`load_scene`, :func:`import_mocap_scene`, :func:`read_bvh`,
                       :func:`write_bvh` (docs/scene_format.md)
results                :func:`load_result`, :class:`Result` (docs/result_format.md)
Ye & Liu 2012          :func:`synthesize`, :class:`SynthesisResult` (docs/synthesis.md)
Liu 2009               :func:`manipulate`, :func:`load_grasp`, :class:`Grasp` (docs/manipulation.md)
Majkowska et al. 2006  :func:`torchhand.splice.splice` (docs/splice.md)
Kry & Pai 2006         the package :mod:`torchhand.interaction` (docs/interaction_capture.md)
checking and export    :func:`check_result`, :class:`CheckReport` (docs/check.md), :func:`export_result`
                       (docs/export.md)
reproducible numbers   :func:`reproducible`, :class:`NumericsProfile` (docs/synthesis.md)
errors                 :class:`TorchhandError` and its subclasses
=====================  ==================================================================================

Below these, the packages (docs/architecture.md): :mod:`torchhand.kernels` (batched tensor kernels),
:mod:`torchhand.solvers` (QP and LCP front doors), :mod:`torchhand.geometry`, :mod:`torchhand.hand`,
:mod:`torchhand.scene`, :mod:`torchhand.io`. Modules whose name starts with ``_`` are private. See
:mod:`torchhand.conventions` for units, frames and shape conventions.
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
    "RigidObject": ".geometry.objects",
    "load_object": ".geometry.objects",
    "SDFGrid": ".geometry.sdf",
    "Scene": ".scene",
    "load_scene": ".scene",
    "import_mocap_scene": ".scene.mocap",
    "read_bvh": ".scene.bvh",
    "write_bvh": ".scene.bvh",
    "load_result": ".io.result",
    "Result": ".io.result",
    "synthesize": ".synthesis.pipeline",
    "SynthesisResult": ".synthesis.pipeline",
    "manipulate": ".manipulation",
    "load_grasp": ".manipulation",
    "Grasp": ".manipulation",
    "check_result": ".check",
    "CheckReport": ".check",
    "export_result": ".export",
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
