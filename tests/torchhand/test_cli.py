"""The `torchhand` command line: --help everywhere, the hand and inspect commands, one-line errors with exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from torchhand.cli import build_parser, main


def _subcommands(parser, prefix=()):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield prefix + (name,)
                yield from _subcommands(sub, prefix + (name,))


def test_every_subcommand_has_help(capsys):
    paths = list(_subcommands(build_parser()))
    assert {("scene",), ("hand",), ("inspect",)} <= set(paths)
    for path in paths:
        with pytest.raises(SystemExit) as exc:
            main(list(path) + ["--help"])
        assert exc.value.code == 0
        assert "usage: torchhand" in capsys.readouterr().out


def test_hand_show_and_export(tmp_path, capsys):
    assert main(["hand", "show", "--side", "left"]) == 0
    out = capsys.readouterr().out
    assert "30 joints" in out and "thumb_cmc_flex" in out
    path = tmp_path / "hand.xml"
    assert main(["hand", "export-mjcf", str(path)]) == 0
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_path(str(path))
    assert model.nq == 7 + 30


def test_inspect_writes_report(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["inspect", "box-turn", "--out", str(out), "--no-progress", "--voxel", "0.004"]) == 0
    report = json.loads((out / "inspect.json").read_text())
    assert report["scene"] == "box-turn" and report["frames"] > 10
    hand = report["hands"]["right"]
    assert len(hand["fingertip_distance_min_m"]) == 5
    # The wrist trajectory brings the hand to the box: some fingertip gets within a few centimetres.
    assert min(hand["fingertip_distance_min_m"]) < 0.05
    assert report["environment"]["frames_with_table_contact"] == report["frames"]
    assert (out / "hand.xml").exists() and (out / "scene" / "scene.toml").exists()


@pytest.mark.parametrize("argv, needle", [
    (["inspect", "no-such-scene", "--out", "{tmp}/x"], "no-such-scene"),
    (["hand", "show", "--mjcf", "{tmp}/missing.xml"], "missing.xml"),
    (["hand", "show", "--length", "7"], "length"),
])
def test_errors_are_one_line_with_exit_code_2(argv, needle, tmp_path):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    proc = subprocess.run([sys.executable, "-m", "torchhand.cli", *argv], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = [l for l in proc.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("torchhand: error:") and needle in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_hand_show_prints_masses(capsys):
    from torchhand.cli import main

    assert main(["hand", "show"]) == 0
    out = capsys.readouterr().out
    assert "total mass 0.4200 kg" in out and "Winter" in out
    assert main(["hand", "show", "--length", "0.095"]) == 0
    assert "total mass 0.0525 kg" in capsys.readouterr().out          # length^3: 0.42 / 8
