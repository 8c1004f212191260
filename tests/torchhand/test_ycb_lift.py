"""The DexYCB-style grasp-and-lift on a real scanned object (torchhand.scene.builtin.ycb, docs/manipulation.md): the
YCB mustard bottle scan of the shared data with its published mass, the Shadow hand under a 6-joint arm given as a
qpos vector, ``grasp from-qpos`` then ``manipulate`` then the checker. Skipped without the shared data."""

from __future__ import annotations

import resource
import subprocess
import sys

import numpy as np
import pytest
import torch

from tests.conftest import shared_path
from torchhand.errors import MissingFileError
from torchhand.scene.builtin.ycb import REST, YCB_MASS, ycb_lift_case

mujoco = pytest.importorskip("mujoco")

_GRASP_MEMORY = 8 << 30        # bytes of address space the grasp step may use (it runs in a child process)
_CLI = "import sys; from torchhand.cli import main; sys.exit(main(sys.argv[1:]))"


def _limit_memory():
    resource.setrlimit(resource.RLIMIT_AS, (_GRASP_MEMORY, _GRASP_MEMORY))


def test_ycb_lift_without_the_shared_data(tmp_path):
    with pytest.raises(MissingFileError, match="006_mustard_bottle") as err:
        ycb_lift_case(tmp_path / "nothing", tmp_path / "out")
    assert "\n" not in str(err.value)


def test_ycb_mustard_lift_from_a_qpos(tmp_path):
    """The case built from the shared data; the grasp from the arm's qpos puts the fingertips where MuJoCo poses
    them (1e-9 m); the lift completes, passes the check, uses the published mass, and at least three contacts carry
    force during the lift."""
    import torchhand
    from torchhand.check import check_result
    from torchhand.cli import main
    from torchhand.hand._compile import compile_file
    from torchhand.manipulation import grasp_from_qpos, grasp_hand

    shared = shared_path("meshes", "ycb", "006_mustard_bottle", "textured.obj").parents[3]
    shared_path("hands", "shadow_hand", "right_hand.xml")
    case = ycb_lift_case(shared, tmp_path / "case")
    assert case.mass == YCB_MASS["006_mustard_bottle"] == 0.603
    scene = torchhand.load_scene(case.scene)
    assert scene.object.mass == pytest.approx(0.603, abs=1e-12) and scene.T == 48
    assert float(scene.object_pose[-1, 2, 3] - scene.object_pose[0, 2, 3]) == pytest.approx(0.10, abs=1e-12)

    # the grasp of the qpos: its fingertips where MuJoCo puts the arm model's distal bodies
    qpos = np.load(case.qpos)
    g = grasp_from_qpos(case.arm, qpos, scene, frame=case.frame)
    hand = grasp_hand(g)
    T_wo = scene.object_pose[case.frame].double().numpy()
    T = hand.forward_kinematics(torch.as_tensor(g.q)[None], torch.as_tensor(T_wo @ g.wrist_in_object)[None])[0]
    ours = ((T[hand.distal_link, :3, :3] @ hand.fingertip[:, :, None]).squeeze(-1) + T[hand.distal_link, :3, 3]).numpy()
    m = compile_file(case.arm)
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, hand.link_names[int(i)]) for i in hand.distal_link]
    tip = hand.fingertip.double().numpy()
    ref = np.stack([d.xmat[b].reshape(3, 3) @ tip[f] + d.xpos[b] for f, b in enumerate(ids)])
    assert float(np.abs(ours - ref).max()) < 1e-9

    # the three commands; the grasp step (the snap's exact distances to the 16k-face scan) in a child process
    # with bounded memory
    gpath, res = tmp_path / "grasp.npz", tmp_path / "result"
    run = subprocess.run([sys.executable, "-c", _CLI, "grasp", "from-qpos", str(case.arm), "--qpos", str(case.qpos),
                          "--scene", str(case.scene), "--frame", str(case.frame), "--out", str(gpath)],
                         capture_output=True, text=True, preexec_fn=_limit_memory, timeout=300, check=False)
    assert run.returncode == 0, f"grasp from-qpos failed: {run.stderr.strip()[-2000:]}"
    assert main(["manipulate", str(case.scene), "--grasp", str(gpath), "--out", str(res), "--threads", "1",
                 "--no-progress"]) == 0
    report = check_result(res)
    assert report.complete and report.solutions[0].passed, report.solutions[0].failure()
    sol = np.load(res / "solutions" / "sol_000.npz")
    assert float(sol["mass"]) == pytest.approx(0.603, abs=1e-12)
    force = np.linalg.norm(sol["contact_force"], axis=-1)           # (T, K)
    slot = sol["contact_slot"]
    lift = slice(REST, REST + 30)
    carrying = {int(s) for s, f in zip(slot[lift].ravel(), force[lift].ravel()) if s >= 0 and f > 0.1}
    assert len(carrying) >= 3, f"contacts carrying force during the lift: {sorted(carrying)}"
