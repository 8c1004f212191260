"""The glTF export (:mod:`torchhand.export.gltf`): the .glb parsed with pygltflib and its node transforms composed
with NumPy against torchhand's FK; then Blender's own glTF importer (``io_scene_gltf2``, shipped in the ``bpy``
wheel) as the client.

What Blender does with the file (Blender 4.5): every node becomes an object named as the node (empties for nodes
without a mesh), y-up is turned back into z-up (world positions equal torchhand's), and keyframe time ``s`` lands
on frame ``s * fps`` (``scene.render.fps``), so glTF frame ``t`` is Blender frame ``t`` (from 0, not 1).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhand.errors import InputTypeError, InputValueError
from torchhand.export.gltf import Y_UP_ROTATION, link_node_names, solution_glb, write_solution_glb
from torchhand.io.result import load_result

from tests.render.fixture_result import write_fixture_result

pygltflib = pytest.importorskip("pygltflib", reason="pygltflib is needed to read the .glb back")

# torchhand (x, y, z) -> glTF (x, z, -y)
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
FIXTURES = {"one": ("box-turn", 10, 2, 1), "two": ("two-hand-box", 4, 1, 0)}   # scene, frames, solutions, index


@pytest.fixture(scope="module", params=sorted(FIXTURES))
def case(request, tmp_path_factory):
    scene, frames, solutions, index = FIXTURES[request.param]
    root = write_fixture_result(tmp_path_factory.mktemp(request.param) / "r", scene, frames=frames,
                                solutions=solutions)
    result = load_result(root)
    return result, index, solution_glb(result, index, contacts=True)


# ---------------------------------------------------------------------------------------------------------------
# Reading the .glb back


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


class Glb:
    """A parsed .glb: accessors decoded with NumPy, node transforms composed at a keyframe."""

    def __init__(self, data: bytes):
        assert data[:4] == b"glTF"
        self.g = pygltflib.GLTF2.load_from_bytes(data)
        self.blob = self.g.binary_blob()
        self.names = {n.name: i for i, n in enumerate(self.g.nodes)}
        self.parent = {c: i for i, n in enumerate(self.g.nodes) for c in n.children}
        self.anim = self.g.animations[0]
        self.channels = {(c.target.node, c.target.path): self.anim.samplers[c.sampler] for c in self.anim.channels}

    def accessor(self, i: int) -> np.ndarray:
        a = self.g.accessors[i]
        view = self.g.bufferViews[a.bufferView]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[a.type]
        dtype = {pygltflib.FLOAT: np.float32, pygltflib.UNSIGNED_INT: np.uint32}[a.componentType]
        return np.frombuffer(self.blob, dtype, a.count * width,
                             view.byteOffset + (a.byteOffset or 0)).reshape(a.count, width).astype(np.float64)

    def value(self, node: int, path: str, t: int, default) -> np.ndarray:
        s = self.channels.get((node, path))
        if s is not None:
            return self.accessor(s.output)[t]
        static = getattr(self.g.nodes[node], path)
        return np.array(default if static is None else static, dtype=np.float64)

    def local(self, node: int, t: int) -> np.ndarray:
        M = np.eye(4)
        M[:3, :3] = _quat_matrix(self.value(node, "rotation", t, [0, 0, 0, 1])) * self.value(node, "scale", t, [1] * 3)
        M[:3, 3] = self.value(node, "translation", t, [0, 0, 0])
        return M

    def world(self, name: str, t: int) -> np.ndarray:
        """The node's pose at keyframe t in torchhand's world: below the ``world`` node, undoing its rotation."""
        i, M = self.names[name], np.eye(4)
        while i != self.names["world"]:
            M = self.local(i, t) @ M
            i = self.parent[i]
        return M


def _fk(result, sol):
    """side -> (link poses (T, L, 4, 4), fingertip positions (T, F, 3)), torchhand world."""
    out = {}
    for h in sol.hands:
        model = result.hand_models[h.side].to(dtype=torch.float64)
        Tw = model.forward_kinematics(torch.from_numpy(h.q), torch.from_numpy(h.root_pose)).numpy()
        D = Tw[:, model.distal_link.numpy()]
        out[h.side] = Tw, (D[..., :3, :3] @ model.fingertip.numpy()[:, :, None])[..., 0] + D[..., :3, 3]
    return out


# ---------------------------------------------------------------------------------------------------------------
# Structure and transforms (no Blender)


def test_structure(case):
    result, index, data = case
    sol = result.solution(index)
    T, K = sol.T, sol.contact_mask.shape[1]
    glb = Glb(data)
    g = glb.g
    assert g.asset.generator == "torchhand export"
    assert g.scenes[g.scene].extras == {"fps": sol.fps, "frames": T, "solution": index}
    assert [g.nodes[i].name for i in g.scenes[g.scene].nodes] == ["world"]
    world = g.nodes[glb.names["world"]]
    np.testing.assert_allclose(_quat_matrix(np.array(world.rotation)), C, atol=1e-12)
    np.testing.assert_allclose(world.rotation, Y_UP_ROTATION)
    assert len(glb.names) == len(g.nodes)                                            # names are unique
    expected = {"world", "object"} | {f"contact_{k}" for k in range(K)}
    assert ("table" in glb.names) == result.scene.environment.table
    assert glb.parent[glb.names["object"]] == glb.names["world"]
    n_links = 0
    for h in sol.hands:
        model = result.hand_models[h.side]
        n_links += model.num_links
        links = [f"{h.side}/{n}" for n in model.link_names]
        expected |= {f"{h.side}_hand", *links, *(f"{h.side}/{f}_tip" for f in model.finger_names)}
        assert glb.parent[glb.names[f"{h.side}_hand"]] == glb.names["world"]
        hand_nodes = [n for n in glb.names if n.startswith(f"{h.side}/") and not n.endswith("_tip")]
        assert sorted(hand_nodes) == sorted(links)                                   # one node per link
        for l, p in enumerate(model.chain.link_parent.tolist()):
            want = f"{h.side}_hand" if p < 0 else links[p]
            assert glb.parent[glb.names[links[l]]] == glb.names[want]
            assert g.nodes[glb.names[links[l]]].mesh is not None                    # every default link has geoms
        for f, d in zip(model.finger_names, model.distal_link.tolist()):
            tip = g.nodes[glb.names[f"{h.side}/{f}_tip"]]
            assert glb.parent[glb.names[f"{h.side}/{f}_tip"]] == glb.names[links[d]]
            assert tip.mesh is None and not tip.children
    assert expected <= set(glb.names)
    assert set(glb.names) - expected <= {"table"}

    # one animation, every channel on the shared time accessor
    assert len(g.animations) == 1 and glb.anim.name == f"solution_{index:03d}"
    assert len(glb.anim.channels) == 2 + 2 * n_links + 2 * K
    assert {s.input for s in glb.anim.samplers} == {glb.anim.samplers[0].input}
    time_acc = g.accessors[glb.anim.samplers[0].input]
    times = glb.accessor(glb.anim.samplers[0].input)[:, 0]
    assert time_acc.count == T and len(times) == T
    np.testing.assert_allclose(times, np.arange(T) / sol.fps, rtol=1e-6)
    assert time_acc.min == [0.0] and time_acc.max[0] == pytest.approx((T - 1) / sol.fps, rel=1e-6)
    for (node, path), s in glb.channels.items():
        out = glb.accessor(s.output)
        assert len(out) == T
        assert s.interpolation == ("STEP" if path == "scale" else "LINEAR")
        if path == "rotation":
            np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-6)
            assert np.all(np.sum(out[1:] * out[:-1], axis=1) >= 0)                  # sign-continuous

    # binary layout: 4-byte aligned views, POSITION min/max, uint32 indices
    assert all(v.byteOffset % 4 == 0 for v in g.bufferViews)
    for mesh in g.meshes:
        for prim in mesh.primitives:
            pos = glb.accessor(prim.attributes.POSITION)
            acc = g.accessors[prim.attributes.POSITION]
            np.testing.assert_array_equal(acc.min, pos.min(0))
            np.testing.assert_array_equal(acc.max, pos.max(0))
            assert g.accessors[prim.indices].componentType == pygltflib.UNSIGNED_INT
            assert glb.accessor(prim.indices).max() < len(pos)


def test_transforms_match_fk(case):
    result, index, data = case
    sol = result.solution(index)
    glb = Glb(data)
    fk = _fk(result, sol)
    T = sol.T
    for t in range(T):
        obj = glb.world("object", t)
        np.testing.assert_allclose(obj[:3, 3], sol.object_pose[t, :3, 3], rtol=0, atol=1e-6)
        np.testing.assert_allclose(obj[:3, :3], sol.object_pose[t, :3, :3], rtol=0, atol=1e-6)
        for h in sol.hands:
            model = result.hand_models[h.side]
            Tw, tips = fk[h.side]
            for f, name in enumerate(model.finger_names):
                np.testing.assert_allclose(glb.world(f"{h.side}/{name}_tip", t)[:3, 3], tips[t, f], rtol=0, atol=1e-5,
                                           err_msg=f"{h.side} {name} tip, frame {t}")
            for l, name in enumerate(model.link_names):
                np.testing.assert_allclose(glb.world(f"{h.side}/{name}", t), Tw[t, l], rtol=0, atol=1e-5,
                                           err_msg=f"{h.side}/{name}, frame {t}")
        # contacts: on the contact point while active, scale 0 otherwise
        for k in range(sol.contact_mask.shape[1]):
            M = glb.world(f"contact_{k}", t)
            if sol.contact_mask[t, k]:
                np.testing.assert_allclose(M[:3, 3], sol.contact_point[t, k], rtol=0, atol=1e-6)
                np.testing.assert_allclose(M[:3, :3], np.eye(3), atol=1e-7)
            else:
                np.testing.assert_array_equal(M[:3, :3], 0.0)
    # the world node's rotation maps torchhand's z-up world into glTF's y-up
    top = glb.local(glb.names["world"], 0) @ glb.world(f"{sol.hands[0].side}/{model.finger_names[0]}_tip", 0)
    np.testing.assert_allclose(top[:3, 3], C @ fk[sol.hands[0].side][1][0, 0], atol=1e-5)


def test_quaternions_unit_continuous_and_exact():
    from torchhand.export.gltf import _quat_xyzw

    rng = np.random.default_rng(0)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.linspace(0, 4 * np.pi, 50)                     # two full turns: every branch, every sign
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle)[:, None, None] * K + (1 - np.cos(angle))[:, None, None] * (K @ K)
    q = _quat_xyzw(R[:, None])[:, 0]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) > 0)
    np.testing.assert_allclose(np.stack([_quat_matrix(x) for x in q]), R, atol=1e-12)
    np.testing.assert_allclose(q[:, :3], np.sin(angle / 2)[:, None] * axis, atol=1e-12)    # continuous from q(0)


def test_link_meshes_of_every_geom_type():
    """Each geom type in its MJCF size semantics, posed in its link frame; links without geoms get no mesh."""
    from types import SimpleNamespace

    from torchhand.export.gltf import _link_meshes
    from torchhand.hand.model import GEOM_TYPES

    kinds = ["capsule", "box", "sphere", "cylinder", "mesh"]
    size = torch.tensor([[0.01, 0.02, 0], [0.01, 0.02, 0.03], [0.015, 0, 0], [0.01, 0.02, 0], [0, 0, 0]],
                        dtype=torch.float64)
    pose = torch.eye(4, dtype=torch.float64).repeat(5, 1, 1)
    pose[:, 0, 3] = torch.arange(5, dtype=torch.float64)             # geom g centred at x = g
    pose[3, :3, :3] = torch.tensor([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # the cylinder along link -y
    tet = (torch.tensor([[0.0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], dtype=torch.float64),
           torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    geoms = SimpleNamespace(link=torch.tensor([0, 0, 2, 2, 2]), type=torch.tensor([GEOM_TYPES.index(k) for k in kinds]),
                            size=size, pose=pose, mesh_index=torch.tensor([-1, -1, -1, -1, 0]), meshes=(tet,))
    out = _link_meshes(SimpleNamespace(geoms=geoms))
    assert sorted(out) == [0, 2]
    v, n, f = out[0]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    assert f.max() < len(v) and len(v) == len(n)
    np.testing.assert_allclose(v.min(0), [-0.01, -0.02, -0.03], atol=1e-9)        # capsule to z = -(0.02 + 0.01)
    np.testing.assert_allclose(v.max(0), [1.01, 0.02, 0.03], atol=1e-9)           # box half-extents at x = 1
    v, n, f = out[2]
    np.testing.assert_allclose(v.min(0), [2 - 0.015, -0.02, -0.015], atol=1e-4)    # sphere, cylinder along y
    np.testing.assert_allclose(v.max(0), [4.01, 0.02, 0.015], atol=1e-4)           # the mesh at x = 4


@pytest.mark.parametrize("name", ["shadow_hand", "allegro_hand"])
def test_robot_hand_meshes_and_tips(case, name):
    """A robot hand from MJCF (mesh geoms) in place of the result's hand: meshes per link, tips where FK puts them."""
    import dataclasses
    from types import SimpleNamespace

    from tests.conftest import shared_path
    from torchhand.hand import HandModel
    from torchhand.io.result import HandSolution

    result, index, _ = case
    model = HandModel.from_mjcf(shared_path("hands", name, "right_hand.xml"))
    sol = result.solution(index)
    T = sol.T
    q = model.random_q(T, torch.Generator().manual_seed(1)).double().numpy()
    root = sol.hands[0].root_pose
    hs = HandSolution(side="right", q=q, joint_names=model.joint_names, root_pose=root)
    fake_sol = dataclasses.replace(sol, hands=(hs,))
    fake = SimpleNamespace(path=result.path, scene=result.scene, solution_files=result.solution_files,
                           hand_models={"right": model}, solution=lambda i: fake_sol)
    glb = Glb(solution_glb(fake, index))
    with_geoms = set(model.geoms.link.tolist())
    names = link_node_names(model, "right")
    assert len(set(glb.names)) == len(glb.g.nodes)
    for l, (link, node) in enumerate(zip(model.link_names, names)):
        assert node == f"right/{link}" + ("_link" if name == "allegro_hand" and link.endswith("_tip") else "")
        if l in with_geoms:
            assert glb.g.nodes[glb.names[node]].mesh is not None
        else:
            assert glb.g.nodes[glb.names[node]].mesh is None
    Tw = _fk(fake, fake_sol)["right"][0]
    for l, node in enumerate(names):
        np.testing.assert_allclose(glb.world(node, T - 1), Tw[T - 1, l], rtol=0, atol=1e-5)
    tips = _fk(fake, fake_sol)["right"][1]
    for t in (0, T - 1):
        for f, finger in enumerate(model.finger_names):
            np.testing.assert_allclose(glb.world(f"right/{finger}_tip", t)[:3, 3], tips[t, f], rtol=0, atol=1e-5)


def test_table(case):
    result, index, data = case
    glb = Glb(data)
    if not result.scene.environment.table:
        assert "table" not in glb.names
        return
    node = glb.g.nodes[glb.names["table"]]
    assert glb.parent[glb.names["table"]] == glb.names["world"] and node.translation is None
    pos = glb.accessor(glb.g.meshes[node.mesh].primitives[0].attributes.POSITION)
    h = result.scene.environment.table_height
    assert pos[:, 2].max() == pytest.approx(h, abs=1e-6) and pos[:, 2].min() == pytest.approx(h - 0.02, abs=1e-6)
    xy = result.solution(index).object_pose[:, :2, 3]
    assert np.all(pos[:, :2].min(0) < xy.min(0) - 0.1) and np.all(pos[:, :2].max(0) > xy.max(0) + 0.1)


def test_without_contacts_and_write(case, tmp_path):
    result, index, _ = case
    data = solution_glb(result, index)
    glb = Glb(data)
    assert not [n for n in glb.names if n.startswith("contact_")]
    assert len(glb.anim.channels) == 2 + 2 * sum(result.hand_models[h.side].num_links
                                                 for h in result.solution(index).hands)
    path = write_solution_glb(result, index, tmp_path / "sub" / "sol.glb")
    assert path == tmp_path / "sub" / "sol.glb" and path.read_bytes() == data
    assert [p.name for p in path.parent.iterdir()] == ["sol.glb"]


def test_bad_input(case):
    result, _, _ = case
    n = len(result.solution_files)
    for bad in (-1, n):
        with pytest.raises(InputValueError, match="index"):
            solution_glb(result, bad)
    with pytest.raises(InputTypeError, match="index"):
        solution_glb(result, "0")
    with pytest.raises(InputValueError, match="contact_radius"):
        solution_glb(result, 0, contacts=True, contact_radius=0.0)


# ---------------------------------------------------------------------------------------------------------------
# Blender as the client


@pytest.mark.blender
def test_blender_imports_glb(bpy, case, tmp_path):
    result, index, data = case
    sol = result.solution(index)
    T, fps = sol.T, sol.fps
    assert fps == int(fps)
    path = tmp_path / "sol.glb"
    path.write_bytes(data)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(fps), 1.0
    assert bpy.ops.import_scene.gltf(filepath=str(path)) == {"FINISHED"}

    glb = Glb(data)
    assert set(glb.names) <= {ob.name for ob in bpy.data.objects}                    # every node, by its name
    action = bpy.data.objects["object"].animation_data.action
    assert action.name == f"solution_{index:03d}"
    assert tuple(action.frame_range) == (0.0, float(T - 1))                            # T frames, from frame 0
    fk = _fk(result, sol)
    worst = 0.0
    for t in (0, T // 2, T - 1):
        scene.frame_set(t)
        got = np.array(bpy.data.objects["object"].matrix_world.translation)
        worst = max(worst, np.abs(got - sol.object_pose[t, :3, 3]).max())
        np.testing.assert_allclose(got, sol.object_pose[t, :3, 3], rtol=0, atol=1e-3, err_msg=f"object, frame {t}")
        com = np.append(result.scene.object.com, 1.0)                                  # the object's centre of mass
        got_com = (np.array(bpy.data.objects["object"].matrix_world) @ com)[:3]
        np.testing.assert_allclose(got_com, (sol.object_pose[t] @ com)[:3], rtol=0, atol=1e-3,
                                   err_msg=f"object centre of mass, frame {t}")
        for h in sol.hands:
            for f, name in enumerate(result.hand_models[h.side].finger_names):
                got = np.array(bpy.data.objects[f"{h.side}/{name}_tip"].matrix_world.translation)
                want = fk[h.side][1][t, f]
                worst = max(worst, np.abs(got - want).max())
                np.testing.assert_allclose(got, want, rtol=0, atol=1e-3, err_msg=f"{h.side} {name} tip, frame {t}")
        for k in range(sol.contact_mask.shape[1]):
            ob = bpy.data.objects[f"contact_{k}"]
            assert np.array(ob.matrix_world.to_scale()) == pytest.approx([float(sol.contact_mask[t, k])] * 3,
                                                                          abs=1e-6)
            if sol.contact_mask[t, k]:
                np.testing.assert_allclose(np.array(ob.matrix_world.translation), sol.contact_point[t, k], atol=1e-3)
    assert worst < 1e-5                                        # float32 keys: far below the 1 mm asked for
