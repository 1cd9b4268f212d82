"""The arrows between packages and modules point one way (README, Layout).

Imports are read from the source with ast (every `import`, including those inside functions), so a
lazy import counts as much as a top-level one: a circle is a circle whenever it is walked.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# package -> the folder its import name is relative to
PACKAGES = {
    "models": ROOT,
    "jobqueue": ROOT,
    "worker": ROOT,
    "service": ROOT,
    "magnet_client": ROOT / "client",
}
# which of our packages each package may import (anything else of ours is a wrong-way arrow)
ALLOWED = {
    "models": set(),
    "jobqueue": set(),
    "worker": {"jobqueue", "models"},
    "service": {"jobqueue", "models"},
    "magnet_client": set(),
}


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg, base in PACKAGES.items():
        for f in (base / pkg).rglob("*.py"):
            name = ".".join(f.relative_to(base).with_suffix("").parts)
            mods[name.removesuffix(".__init__")] = f
    return mods


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """Our modules that `name` imports (relative imports resolved; `from pkg import mod` counted)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return {m for m in found if m in known and m != name}


def import_graph() -> dict[str, set[str]]:
    mods = _modules()
    return {name: _imports(name, path, set(mods)) for name, path in mods.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan, iterative)."""
    index, low, stack, on_stack, out, counter = {}, {}, [], set(), [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[v] = min(low[v], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_cycle_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle_between_modules():
    graph = import_graph()
    assert "models.learn.dataset" in graph and "worker.tasks" in graph and "jobqueue.db" in graph
    assert cycles(graph) == []


def test_packages_import_only_downstream():
    wrong = sorted(
        f"{name} imports {target}"
        for name, targets in import_graph().items()
        for target in targets
        if (src := name.split(".")[0]) != (dst := target.split(".")[0]) and dst not in ALLOWED[src]
    )
    assert wrong == []
    package_graph: dict[str, set[str]] = {pkg: set() for pkg in PACKAGES}
    for name, targets in import_graph().items():
        package_graph[name.split(".")[0]].update(t.split(".")[0] for t in targets)
    assert cycles({p: t - {p} for p, t in package_graph.items()}) == []


# models/ from the ground up: each subpackage (or top-level module) may import only those before it
MODELS_FLOORS = [
    "models.errors",
    "models.params",
    "models.native",
    "models.graph",
    "models.mesh",
    "models.nets",
    "models.partition",
    "models.polytope",
    "models.quality",
    "models.export",
    "models.hierarchy",
    "models.pipeline",
    "models.agglomeration",
    "models.api",
    "models.learn",
    "models.cli",
]


def _floor(module: str) -> int | None:
    for i, prefix in enumerate(MODELS_FLOORS):
        if module == prefix or module.startswith(prefix + "."):
            return i
    return None


def test_models_subpackages_import_only_downward():
    graph = import_graph()
    unplaced = sorted(m for m in graph if m.startswith("models.") and _floor(m) is None)
    assert unplaced == [], f"modules in no floor of MODELS_FLOORS: {unplaced}"
    upward = sorted(
        f"{name} imports {target}"
        for name, targets in graph.items()
        if name.startswith("models.")
        for target in targets
        if target.startswith("models.") and _floor(target) > _floor(name)
    )
    assert upward == []
