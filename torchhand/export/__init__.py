"""Results out to animation tools: BVH, glTF and FBX per solution, and fingers written back onto a captured body.

``torchhand export RESULT_DIR --out DIR`` (docs/export.md). Modules: :mod:`.skeleton` (a hand model as a BVH
skeleton and its motion as channels), :mod:`.gltf` (a solution as a .glb scene), :mod:`.onto` (fingers onto the
body BVH a scene was imported from), :mod:`.fbx` (a solution or a body as an FBX job; Blender found and run) with
its Blender-side script :mod:`._blender_fbx`, :mod:`.export` (the result directory in, the files out).
"""

from .export import ExportReport, export_result
from .fbx import BlenderRunner, FbxScene, find_blender, write_fbx

__all__ = ["ExportReport", "export_result", "BlenderRunner", "FbxScene", "find_blender", "write_fbx"]
