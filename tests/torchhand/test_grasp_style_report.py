"""scripts/grasp_style_report.py: which links are the palm, and the palm's share of the frames the hand carries."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))

from grasp_style_report import main, palm_names  # noqa: E402

NAMES = ["palm", "thumb_metacarpal", "thumb_proximal", "thumb_distal"] + [
    f"{f}_{s}" for f in ("index", "middle", "ring", "little") for s in ("metacarpal", "proximal", "middle", "distal")]


def test_the_palm_is_the_palm_link_and_four_link_metacarpals():
    assert palm_names(NAMES) == {"palm", "index_metacarpal", "middle_metacarpal", "ring_metacarpal",
                                 "little_metacarpal"}


def _result(tmp_path: Path, palm_force: list[float], table: list[bool]) -> Path:
    """A result folder of one solution, T frames: contact 0 on the palm with the given normal force, contact 1 on the
    index fingertip with 1 N, table contacts where ``table``; an object of 0.1 kg."""
    T = len(palm_force)
    out = tmp_path / "r"
    (out / "solutions").mkdir(parents=True)
    (out / "scene").mkdir()
    (out / "scene" / "scene.toml").write_text('[scene]\ngravity = [0.0, 0.0, -10.0]\n[object]\nmass = 0.1\n')
    normal = np.tile([0.0, 0.0, 1.0], (T, 2, 1))
    force = normal * np.stack([np.asarray(palm_force), np.ones(T)], 1)[..., None]
    env = np.zeros((T, 1, 3))
    env[np.asarray(table), 0, 2] = 1.0
    np.savez(out / "solutions" / "sol_000.npz", contact_link_name=np.array(NAMES), contact_mask=np.ones((T, 2), bool),
             contact_link=np.tile([0, NAMES.index("index_distal")], (T, 1)), contact_normal=normal,
             contact_force=force, env_contact_force=env)
    return out


def test_shares_count_carried_frames_and_a_force_threshold(tmp_path, capsys):
    # 4 frames on the table, 6 carried; the palm pushes 0.5 N (half the weight) on 3 carried frames, 0.01 N on one
    palm = [0.5, 0.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.01, 0.0, 0.0]
    table = [True, True, True, True, False, False, False, False, False, False]
    out = _result(tmp_path, palm, table)
    report = tmp_path / "report.json"
    assert main([str(out), "--json", str(report)]) == 0
    import json
    row = json.loads(report.read_text())[str(out)][0]
    assert row["carried"] == 6 and row["touching"] == 10
    assert row["palm_share_of_carried"] == 0.5            # 3 of 6 (0.01 N < 0.02 x 1 N)
    assert row["palm_share_of_frames"] == 0.4             # 4 of 10
    assert abs(row["palm_share_of_force"] - sum(palm) / (sum(palm) + 10)) < 1e-12
    assert "50%" in capsys.readouterr().out
