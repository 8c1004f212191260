"""Packaging and the dependency direction: kernels stay pure, a regular install ships torchhand.kernels/.render."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
KERNELS = sorted(p.stem for p in (REPO / "kernels").glob("*.py") if p.stem != "__init__")


def _run(code: str, **kw) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, **kw)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_kernels_import_pulls_no_orchestration_or_rendering():
    code = (
        "import sys, json\n"
        + "".join(f"import torchhand.kernels.{k}\n" for k in KERNELS)
        + "print(json.dumps(sorted(m for m in sys.modules if m.startswith(('torchhand', 'pyrender', 'trimesh', "
        "'kornia', 'imageio', 'OpenGL')))))"
    )
    mods = json.loads(_run(code, cwd=REPO))
    allowed = {"torchhand", "torchhand.errors", "torchhand.kernels"} | {f"torchhand.kernels.{k}" for k in KERNELS}
    assert set(mods) <= allowed, sorted(set(mods) - allowed)


def test_kernel_sources_import_only_torch_and_math():
    import ast

    for k in KERNELS:
        tree = ast.parse((REPO / "kernels" / f"{k}.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [] if node.level else [(node.module or "").split(".")[0]]
            else:
                continue
            assert set(names) <= {"torch", "math", "__future__", "typing", "dataclasses", "enum"}, (k, names)


@pytest.mark.slow
def test_regular_install_ships_kernels_and_render(tmp_path):
    target = tmp_path / "site"
    build = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-compile", "-q",
         "--target", str(target), str(REPO)],
        capture_output=True, text=True, timeout=600,
    )
    assert build.returncode == 0, build.stderr[-2000:]
    # Nothing generic at the top level of site-packages: only torchhand and its metadata.
    top = {p.name for p in target.iterdir() if not p.name.endswith((".dist-info", ".egg-info")) and p.name != "bin"}
    assert top == {"torchhand"}, top
    assert (target / "torchhand" / "kernels" / "kinematics.py").exists()
    assert (target / "torchhand" / "render" / "__init__.py").exists()
    # Every source package is installed (the explicit package list in pyproject.toml is complete).
    for init in (REPO / "torchhand").rglob("__init__.py"):
        rel = init.relative_to(REPO)
        assert (target / rel).exists(), f"{rel.parent} is missing from [tool.setuptools] packages"
    env = dict(os.environ, PYTHONPATH=str(target))
    out = _run("import torchhand, torchhand.kernels.kinematics, torchhand.render; "
               "print(torchhand.__file__); print(torchhand.kernels.kinematics.__file__)", cwd=tmp_path, env=env)
    for line in out.split():
        assert line.startswith(str(target)), line
