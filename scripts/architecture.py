"""Measure torchhand's architecture: import circles, layer violations, module and function sizes.

    python scripts/architecture.py            # the figures, human readable
    python scripts/architecture.py --json     # the same as JSON

A function over the limit is an exception only in ``torchhand.kernels`` (its solver loops) and only when the comment
right above its ``def`` (or its first decorator) starts ``# long function: <reason>`` (the reason may run on over
more comment lines).

Every import statement counts, also those inside functions (a lazy import is still a dependency); imports under
``if TYPE_CHECKING:`` do not. Modules are named as they are imported (``torchhand.kernels`` lives in ``kernels/``).
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# import name -> directory, as pyproject.toml's package-dir says
PACKAGE_DIRS = {"torchhand": ROOT / "torchhand", "torchhand.kernels": ROOT / "kernels",
                "torchhand.render": ROOT / "render"}
# The layers, bottom to top (docs/architecture.md). A module may import modules of a lower layer and of its own
# unit (an entry of the table: a package or a module), nothing else: not a higher layer, not another unit of its
# own layer (peers stay independent). ``torchhand`` itself is the public facade: it imports only errors at import
# time and resolves the rest lazily by name.
LAYERS = [
    ("errors", ["torchhand.errors"]),
    ("foundation", ["torchhand", "torchhand.conventions", "torchhand._tree", "torchhand._atomic", "torchhand._npz",
                    "torchhand._numerics"]),
    ("kernels", ["torchhand.kernels"]),
    ("solvers and geometry", ["torchhand.solvers", "torchhand.geometry"]),
    ("hand", ["torchhand.hand"]),
    ("scene", ["torchhand.scene"]),
    ("result files", ["torchhand.io"]),
    ("checker", ["torchhand.check"]),
    ("synthesis", ["torchhand.synthesis"]),
    ("methods", ["torchhand.interaction", "torchhand.manipulation", "torchhand.splice", "torchhand.fill"]),
    ("export and render", ["torchhand.export", "torchhand.render"]),
    ("viewer", ["torchhand.view"]),
    ("batch", ["torchhand.batch"]),
    ("cli", ["torchhand.cli"]),
]
MODULE_LINES = 500
FUNCTION_LINES = 100
EXCEPTION_MARK = "# long function:"
EXCEPTION_PACKAGES = ("torchhand.kernels",)


@dataclass
class Module:
    name: str
    path: Path
    is_package: bool
    lines: int
    source_lines: list[str] = field(default_factory=list)
    imports: set[str] = field(default_factory=set)
    functions: list[tuple[str, int, int]] = field(default_factory=list)   # (qualified name, first line, length)
    exceptions: dict[str, str] = field(default_factory=dict)               # qualified name -> reason


def discover() -> dict[str, Module]:
    modules: dict[str, Module] = {}
    for prefix, base in PACKAGE_DIRS.items():
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(base).with_suffix("")
            parts = list(rel.parts)
            is_package = parts[-1] == "__init__"
            if is_package:
                parts = parts[:-1]
            name = ".".join([prefix, *parts])
            if name in modules:          # kernels/ under torchhand/kernels would collide; first one wins
                continue
            text = path.read_text(encoding="utf-8")
            modules[name] = Module(name, path, is_package, len(text.splitlines()), text.splitlines())
    return modules


def _type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _resolve(mod: Module, node: ast.ImportFrom | ast.Import, known: set[str]) -> set[str]:
    out: set[str] = set()
    if isinstance(node, ast.Import):
        for alias in node.names:
            name = alias.name
            while name and name not in known:
                name = name.rpartition(".")[0]
            if name:
                out.add(name)
        return out
    if node.level:
        package = mod.name if mod.is_package else mod.name.rpartition(".")[0]
        for _ in range(node.level - 1):
            package = package.rpartition(".")[0]
        base = f"{package}.{node.module}" if node.module else package
    else:
        base = node.module or ""
    target = base
    while target and target not in known:
        target = target.rpartition(".")[0]
    if not target:
        return out
    if target == base:
        for alias in node.names:       # from pkg import submodule
            sub = f"{base}.{alias.name}"
            out.add(sub if sub in known else base)
    else:
        out.add(target)
    return out


def _walk(mod: Module, tree: ast.AST, known: set[str]) -> None:
    def visit(node: ast.AST, scope: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                for sub in child.orelse:
                    visit(sub, scope)
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                mod.imports |= _resolve(mod, child, known)
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                qual = f"{scope}{child.name}"
                length = (child.end_lineno or child.lineno) - child.lineno + 1
                mod.functions.append((qual, child.lineno, length))
                first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                block = []                    # the comment lines right above the def (or its first decorator)
                k = first - 2
                while k >= 0 and mod.source_lines[k].strip().startswith("#"):
                    block.insert(0, mod.source_lines[k].strip())
                    k -= 1
                if block and block[0].startswith(EXCEPTION_MARK):
                    text = " ".join(b.lstrip("#").strip() for b in block)
                    mod.exceptions[qual] = text[len(EXCEPTION_MARK) - 2:].strip()
                visit(child, qual + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{scope}{child.name}.")
            else:
                visit(child, scope)
    visit(tree, "")


def analyse() -> dict[str, Module]:
    modules = discover()
    known = set(modules)
    for mod in modules.values():
        _walk(mod, ast.parse("\n".join(mod.source_lines)), known)
        mod.imports.discard(mod.name)
    return modules


def _edges(modules: dict[str, Module]) -> dict[str, set[str]]:
    """Module -> the modules it imports (a package's ``__init__`` importing its submodules counts too)."""
    return {m.name: set(m.imports) for m in modules.values()}


def circles(modules: dict[str, Module]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    edges = _edges(modules)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return sorted(out)


def unit_of(name: str) -> tuple[int, str] | None:
    """(layer index, unit) of module ``name``: the longest entry of :data:`LAYERS` that is it or contains it."""
    best = None
    for i, (_, units) in enumerate(LAYERS):
        for u in units:
            if (name == u or name.startswith(u + ".")) and (best is None or len(u) > len(best[1])):
                best = (i, u)
    if best and best[1] == "torchhand" and name != "torchhand":
        return None          # a top-level module missing from the table
    return best


def layer_violations(modules: dict[str, Module]) -> list[str]:
    """Imports that do not go downward, and modules that belong to no layer."""
    out = []
    for m in sorted(modules.values(), key=lambda m: m.name):
        here = unit_of(m.name)
        if here is None:
            out.append(f"{m.name}: in no layer of scripts/architecture.py LAYERS")
            continue
        for t in sorted(m.imports):
            there = unit_of(t)
            if there is None or there[1] == here[1] or there[0] < here[0]:
                continue
            what = "a peer" if there[0] == here[0] else "a higher layer"
            out.append(f"{m.name} imports {t} ({what}: {LAYERS[there[0]][0]})")
    return out


def figures(modules: dict[str, Module]) -> dict:
    funcs = [(f"{m.name}.{q}", n) for m in modules.values() for q, _, n in m.functions]
    excepted = {f"{m.name}.{q}": r for m in modules.values() for q, r in m.exceptions.items()
                if m.name.startswith(EXCEPTION_PACKAGES)}
    funcs.sort(key=lambda x: -x[1])
    mods = sorted(((m.name, m.lines) for m in modules.values()), key=lambda x: -x[1])
    return {
        "modules": len(modules),
        "lines": sum(m.lines for m in modules.values()),
        "circles": circles(modules),
        "layer_violations": layer_violations(modules),
        "largest_module": mods[0],
        "modules_over_limit": [x for x in mods if x[1] > MODULE_LINES],
        "largest_function": funcs[0],
        "functions_over_limit": [x for x in funcs if x[1] > FUNCTION_LINES and x[0] not in excepted],
        "function_exceptions": [(n, k, excepted[n]) for n, k in funcs if k > FUNCTION_LINES and n in excepted],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    fig = figures(analyse())
    if args.json:
        print(json.dumps(fig, indent=1))
        return 0
    print(f"{fig['modules']} modules, {fig['lines']} lines")
    print(f"import circles: {len(fig['circles'])}")
    for c in fig["circles"]:
        print("  " + " <-> ".join(c))
    print(f"imports that do not go downward: {len(fig['layer_violations'])}")
    for v in fig["layer_violations"]:
        print("  " + v)
    print(f"largest module: {fig['largest_module'][0]} ({fig['largest_module'][1]} lines)")
    print(f"modules over {MODULE_LINES} lines: {len(fig['modules_over_limit'])}")
    for n, k in fig["modules_over_limit"]:
        print(f"  {k:5d} {n}")
    print(f"largest function: {fig['largest_function'][0]} ({fig['largest_function'][1]} lines)")
    print(f"functions over {FUNCTION_LINES} lines: {len(fig['functions_over_limit'])}")
    for n, k in fig["functions_over_limit"]:
        print(f"  {k:5d} {n}")
    print(f"named exceptions (kernels' solver loops): {len(fig['function_exceptions'])}")
    for n, k, r in fig["function_exceptions"]:
        print(f"  {k:5d} {n}: {r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
