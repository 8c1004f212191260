"""The shape of the code: no import circles, imports only downward, small modules and functions, the public API
resolvable, docs/architecture.md in step with the tree (figures from scripts/architecture.py)."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load_tool():
    spec = importlib.util.spec_from_file_location("_architecture_tool", ROOT / "scripts" / "architecture.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod          # dataclasses look their module up while the class is made
    spec.loader.exec_module(mod)
    return mod


arch = _load_tool()


@pytest.fixture(scope="module")
def figures():
    return arch.figures(arch.analyse())


def test_no_import_circles(figures):
    assert figures["circles"] == [], "import circles:\n" + "\n".join(" <-> ".join(c) for c in figures["circles"])


def test_imports_only_go_downward(figures):
    assert figures["layer_violations"] == [], "\n".join(figures["layer_violations"])


def test_no_module_over_the_limit(figures):
    assert figures["modules_over_limit"] == [], f"modules over {arch.MODULE_LINES} lines: {figures['modules_over_limit']}"


def test_no_function_over_the_limit(figures):
    assert figures["functions_over_limit"] == [], (
        f"functions over {arch.FUNCTION_LINES} lines: {figures['functions_over_limit']}")


def test_long_functions_are_named_kernel_solver_loops_with_a_reason(figures):
    for name, lines, reason in figures["function_exceptions"]:
        assert name.startswith("torchhand.kernels."), name
        assert len(reason) >= 20, f"{name}: the reason is too short to say anything: {reason!r}"


def _toy_package(tmp_path: Path, files: dict[str, str]) -> dict:
    base = tmp_path / "toy"
    for rel, text in files.items():
        (base / rel).parent.mkdir(parents=True, exist_ok=True)
        (base / rel).write_text(text)
    old = arch.PACKAGE_DIRS
    arch.PACKAGE_DIRS = {"torchhand": base}
    try:
        return arch.analyse()
    finally:
        arch.PACKAGE_DIRS = old


def test_the_tool_sees_a_lazy_circle_and_an_upward_import_but_not_a_type_checking_one(tmp_path):
    modules = _toy_package(tmp_path, {
        "__init__.py": "",
        "errors.py": "",
        "scene/__init__.py": "",
        "scene/a.py": "def f():\n    from .b import g\n    return g\n",
        "scene/b.py": "from .a import f\n",
        "hand/__init__.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..cli import x\n",
        "geometry/__init__.py": "from ..hand import y\n",
        "cli/__init__.py": "",
    })
    assert arch.circles(modules) == [["torchhand.scene.a", "torchhand.scene.b"]]
    assert arch.layer_violations(modules) == [
        "torchhand.geometry imports torchhand.hand (a higher layer: hand)"]


def test_the_tool_counts_function_lines_and_honours_only_kernel_exceptions(tmp_path):
    body = "".join(f"    x{i} = {i}\n" for i in range(101))
    modules = _toy_package(tmp_path, {
        "__init__.py": "",
        "kernels/__init__.py": "",
        "kernels/k.py": "# long function: one solver loop whose iterations share state\ndef loop():\n" + body,
        "scene/__init__.py": "# long function: not allowed here\ndef big():\n" + body,
    })
    fig = arch.figures(modules)
    assert [n for n, _ in fig["functions_over_limit"]] == ["torchhand.scene.big"]
    assert [n for n, _, _ in fig["function_exceptions"]] == ["torchhand.kernels.k.loop"]


def test_every_public_name_resolves():
    import torchhand

    for name in torchhand.__all__:
        assert getattr(torchhand, name) is not None, name


def test_architecture_doc_names_every_package_and_nothing_that_is_gone():
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    packages = {p.parent.relative_to(ROOT).as_posix() for p in (ROOT / "torchhand").rglob("__init__.py")}
    packages = (packages - {"torchhand"}) | {"kernels", "render"}
    for pkg in sorted(packages):
        assert f"`{pkg}/`" in doc, f"docs/architecture.md does not describe {pkg}/"
    for named in set(re.findall(r"`((?:torchhand|kernels|render)(?:/[\w.]+)*/?)`", doc)):
        assert (ROOT / named).exists(), f"docs/architecture.md names {named}, which is not in the tree"
    for layer, _ in arch.LAYERS:
        assert layer in doc, f"docs/architecture.md does not name the layer {layer!r}"
