"""Acceptance of ``torchhand batch``: twelve jobs (box-turn, bottle-turn, cube-turn × seeds 0, 1 × the built-in hand
and the Allegro hand from ``../shared/data``) on the local pool and on a local Ray instance with 2 CPUs give the
same jobs, each finished once, with byte-identical solution arrays. A few minutes on 2 CPU cores (the Allegro
hand's check poses MuJoCo meshes), hence ``slow``. (Ray is compared with the local pool only here: a four-job
copy of this comparison in test_batch.py was a subset of it.)"""

from __future__ import annotations

import json

import pytest

from tests.conftest import shared_path
from tests.torchhand.test_batch import SMALL, _arrays, _assert_exactly_once, _events, _job_dirs, _write
from torchhand.batch import load_manifest
from torchhand.cli import main as cli


@pytest.mark.slow
def test_twelve_jobs_on_the_local_pool_and_on_ray_give_identical_arrays(tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'torchhand[ray]')")
    allegro = shared_path("hands", "allegro_hand", "right_hand.xml")
    manifest = _write(tmp_path / "batch.toml", SMALL + '[[jobs]]\nscenes = ["box-turn", "bottle-turn", "cube-turn"]\n'
                      f'seeds = [0, 1]\nhands = ["default", "right={allegro}"]\n')
    ids = set(load_manifest(manifest).ids)
    assert len(ids) == 12
    local, ray = tmp_path / "local", tmp_path / "ray"
    assert cli(["batch", str(manifest), "--out", str(local), "--workers", "2", "--no-progress"]) == 0
    assert cli(["batch", str(manifest), "--out", str(ray), "--workers", "2", "--ray", "auto", "--no-progress"]) == 0
    for out in (local, ray):
        _assert_exactly_once(out, ids)
    assert {e["backend"] for e in _events(ray) if e["event"] == "start"} == {"ray"}
    compared = 0
    for d in _job_dirs(local):
        a, b = _arrays(d), _arrays(ray / "jobs" / d.name)
        s, t = (json.loads((r / "jobs" / d.name / "stats.json").read_text()) for r in (local, ray))
        assert (s["solutions"], s["nodes_tested"], s["dead_ends"], s["threads"]) == (
            t["solutions"], t["nodes_tested"], t["dead_ends"], t["threads"])
        assert len(a) == len(b) == s["solutions"]
        for x, y in zip(a, b):
            assert x.keys() == y.keys()
            for k in x:
                assert x[k].dtype == y[k].dtype and x[k].tobytes() == y[k].tobytes(), (d.name, k)
                compared += 1
    assert compared > 0
