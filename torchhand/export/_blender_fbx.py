"""The Blender side of ``torchhand export --format fbx``: a job file in, an FBX file out.

Runs inside Blender and imports only the standard library, ``bpy`` and ``mathutils`` (never torchhand, torch or
NumPy, so it runs in any Blender):

    blender --background --factory-startup --python _blender_fbx.py -- JOB.json OUT.fbx
    PYTHON_WITH_BPY _blender_fbx.py JOB.json OUT.fbx

The job is written by :mod:`torchhand.export.fbx` (its docstring describes it). This script starts from an empty
scene, sets the frame rate and the frame range ``0 .. frames - 1``, builds each armature (edit bones from the rest
matrices and lengths, each bone keyed per frame with the local location and rotation quaternion that put it at the
job's bone matrix) and each mesh (keyed location and rotation quaternion per frame), and exports with Blender's
FBX exporter (:data:`EXPORT_OPTIONS`): metres declared as the file's unit and written unscaled, the file y-up
(Blender's -Z forward, Y up: the FBX convention, converted back to z-up by Blender's importer), bones Y-primary as
Blender's own, no added leaf bones, every frame baked with no simplification into one animation stack.
"""

import json
import os
import sys

import bpy
from mathutils import Matrix, Quaternion

EXPORT_OPTIONS = dict(
    check_existing=False, use_selection=False, object_types={"ARMATURE", "MESH"}, use_mesh_modifiers=False,
    global_scale=1.0, apply_unit_scale=True, apply_scale_options="FBX_SCALE_UNITS",
    axis_forward="-Z", axis_up="Y", use_space_transform=True, bake_space_transform=False,
    add_leaf_bones=False, primary_bone_axis="Y", secondary_bone_axis="X", armature_nodetype="NULL",
    use_armature_deform_only=False, bake_anim=True, bake_anim_use_all_bones=True, bake_anim_use_nla_strips=False,
    bake_anim_use_all_actions=False, bake_anim_force_startend_keying=True, bake_anim_step=1.0,
    bake_anim_simplify_factor=0.0, mesh_smooth_type="FACE", path_mode="AUTO", embed_textures=False,
)
"""Options of ``bpy.ops.export_scene.fbx`` (module docstring)."""


def _matrix(flat):
    return Matrix([flat[0:4], flat[4:8], flat[8:12], flat[12:16]])


def _fcurves(ob):
    """The F-curves of ``ob``'s action (the slot's channel bag where Blender has slotted actions)."""
    ad = ob.animation_data
    try:
        from bpy_extras.anim_utils import action_get_channelbag_for_slot
    except ImportError:
        return ad.action.fcurves
    return action_get_channelbag_for_slot(ad.action, ad.action_slot).fcurves


def _key(ob, channels, n):
    """Key ``channels`` ({(data_path, index): [n values]}) of ``ob`` at frames 0 .. n - 1 (the exporter samples
    whole frames only, so the keys are what it writes)."""
    by_path = {}
    for path, index in channels:
        by_path.setdefault(path, []).append(index)
    for path in by_path:
        ob.keyframe_insert(data_path=path, frame=0.0)
    for fc in _fcurves(ob):
        values = channels.get((fc.data_path, fc.array_index))
        if values is None:
            continue
        points = fc.keyframe_points
        points.add(n - len(points))
        co = []
        for f, v in enumerate(values):
            co += [float(f), float(v)]
        points.foreach_set("co", co)
        fc.update()


def _quaternions(mats):
    """Rotation quaternions (w, x, y, z) of ``mats``, sign-continuous along the list."""
    out, last = [], None
    for m in mats:
        q = m.to_quaternion().normalized()
        if last is not None and q.dot(last) < 0.0:
            q = Quaternion((-q.w, -q.x, -q.y, -q.z))
        out.append(q)
        last = q
    return out


def _channels(prefix, mats):
    """{(data_path, index): values} of location and rotation_quaternion from rigid matrices ``mats``."""
    out = {}
    quats = _quaternions(mats)
    for i in range(3):
        out[(prefix + "location", i)] = [m.translation[i] for m in mats]
    for i in range(4):
        out[(prefix + "rotation_quaternion", i)] = [q[i] for q in quats]
    return out


def build_armature(spec, n):
    """The armature object of one job entry, its bones in rest pose, keyed over ``n`` frames."""
    data = bpy.data.armatures.new(spec["name"])
    ob = bpy.data.objects.new(spec["name"], data)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.view_layer.objects.active = ob
    bpy.ops.object.mode_set(mode="EDIT")
    edit = []
    for name, parent, rest, length in zip(spec["bones"], spec["parents"], spec["rest"], spec["length"]):
        eb = data.edit_bones.new(name)
        eb.head, eb.tail = (0.0, 0.0, 0.0), (0.0, float(length), 0.0)
        eb.matrix = _matrix(rest)
        if parent >= 0:
            eb.parent = edit[parent]
            eb.use_connect = False
        edit.append(eb)
    bpy.ops.object.mode_set(mode="OBJECT")
    names = list(spec["bones"])
    rest = [data.bones[b].matrix_local.copy() for b in names]         # as Blender stored them
    pose = [[_matrix(m) for m in frame] for frame in spec["pose"]]
    channels = {}
    for j, name in enumerate(names):
        p = spec["parents"][j]
        inv_rest = rest[j].inverted()
        if p < 0:
            local = [inv_rest @ frame[j] for frame in pose]
        else:
            rel = inv_rest @ rest[p]
            local = [rel @ frame[p].inverted() @ frame[j] for frame in pose]
        pb = ob.pose.bones[name]
        pb.rotation_mode = "QUATERNION"
        channels.update(_channels(f'pose.bones["{_escape(name)}"].', local))
    _key(ob, channels, n)
    return ob


def _escape(name):
    return name.replace("\\", "\\\\").replace('"', '\\"')


def build_mesh(spec, n):
    """A mesh object of one job entry, keyed over ``n`` frames."""
    me = bpy.data.meshes.new(spec["name"])
    me.from_pydata([tuple(v) for v in spec["vertices"]], [], [tuple(f) for f in spec["faces"]])
    me.update()
    ob = bpy.data.objects.new(spec["name"], me)
    bpy.context.scene.collection.objects.link(ob)
    ob.rotation_mode = "QUATERNION"
    _key(ob, _channels("", [_matrix(m) for m in spec["pose"]]), n)
    return ob


def build_scene(job):
    """An empty scene with the job's frame rate, frame range, armatures and meshes."""
    if job.get("format") != "torchhand-fbx" or int(job.get("version", 0)) != 1:
        raise ValueError("not a torchhand-fbx version 1 job")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    fps, n = float(job["fps"]), int(job["frames"])
    scene.render.fps = max(1, int(round(fps)))
    scene.render.fps_base = scene.render.fps / fps
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0
    scene.frame_start, scene.frame_end = 0, max(n - 1, 0)
    for spec in job["armatures"]:
        build_armature(spec, n)
    for spec in job["meshes"]:
        build_mesh(spec, n)
    scene.frame_set(0)
    return scene


def main(argv):
    """``argv``: [job.json, out.fbx]; builds the scene and exports it."""
    if len(argv) != 2:
        raise SystemExit("usage: _blender_fbx.py JOB.json OUT.fbx")
    with open(argv[0], encoding="utf-8") as fh:
        job = json.load(fh)
    build_scene(job)
    out = os.path.abspath(argv[1])
    result = bpy.ops.export_scene.fbx(filepath=out, **EXPORT_OPTIONS)
    if result != {"FINISHED"} or not os.path.isfile(out):
        raise RuntimeError(f"Blender's FBX exporter did not write {out} ({result})")
    return out


def _argv(args):
    return args[args.index("--") + 1:] if "--" in args else args[1:]


if __name__ == "__main__":
    try:
        main(_argv(sys.argv))
    except Exception as err:         # report on one line; the caller shows it
        print(f"torchhand fbx: {type(err).__name__}: {err}", file=sys.stderr)
        sys.exit(1)
