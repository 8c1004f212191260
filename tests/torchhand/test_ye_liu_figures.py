"""scripts/ye_liu_figures.py without synthesizing: every panel names a run, runs are read from stats.json, the
Table 1 columns are formatted, and a missing run is named rather than guessed."""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))

import ye_liu_figures as Y  # noqa: E402

from torchhand.scene.builtin import list_builtin_scenes  # noqa: E402


def test_every_panel_names_a_run_of_a_built_in_scene():
    assert {run for _, _, run, _ in Y.DEMOS} <= set(Y.RUNS)
    assert {args[0] for args, _ in Y.RUNS.values()} <= set(list_builtin_scenes())
    assert {fig for fig, _, _, _ in Y.DEMOS} >= {"Table 1", "Fig. 7", "Fig. 8", "Fig. 9"}


def test_the_table_row_comes_from_stats_json(tmp_path, capsys):
    out = tmp_path / "box-turn"
    out.mkdir()
    stats = {"epsilon": 10.0, "T": 66, "time_s": 304.2, "solutions": 10, "dead_ends": 1991, "total_frames": 10610,
             "success_frames": 660, "success_ratio": 0.0622, "solution_ratio": 0.0075, "other": 1}
    (out / "stats.json").write_text(json.dumps(stats))
    assert Y.ensure_run("box-turn", tmp_path, run=False, solutions=3, max_nodes=10) == out
    row = Y.table_row(out)
    assert set(row) == set(Y.COLUMNS) and row["dead_ends"] == 1991
    line = Y.markdown({"box-turn": ("Table 1", row)}).splitlines()[-1]
    assert line == "| box-turn | Table 1 | 10 | 66 | 304 | 10 | 1991 | 10610 | 660 | 6.2% | 0.8% |"
    assert Y.ensure_run("bunny", tmp_path, run=False, solutions=3, max_nodes=10) is None
    err = capsys.readouterr().err
    assert "bunny" in err
