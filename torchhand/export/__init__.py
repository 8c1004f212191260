"""Results out to animation tools: BVH and glTF per solution, and fingers written back onto a captured body.

``torchhand export RESULT_DIR --out DIR`` (docs/export.md). Modules: :mod:`.skeleton` (a hand model as a BVH
skeleton and its motion as channels), :mod:`.gltf` (a solution as a .glb scene), :mod:`.onto` (fingers onto the
body BVH a scene was imported from), :mod:`.export` (the result directory in, the files out).
"""

from .export import ExportReport, export_result

__all__ = ["ExportReport", "export_result"]
