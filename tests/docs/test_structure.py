"""The packages' structure, read from their source (ast): what docs/architecture.md promises.

* No import circle among the modules of ``targets``, ``forward_solver`` and
  ``inverse_design``, counting imports inside functions (a package's
  ``__init__`` importing its own submodules is not a circle).
* No private name (``_x``) imported from another module.
* A function-local import of the project's own code only where a spawned
  worker must not import JAX, marked on its line with ``# (worker: ...)``
  and the reason.
* Data flows one way: ``targets`` imports neither of the others,
  ``forward_solver`` does not import ``inverse_design``, the design library
  does not import its command (``inverse_design.app``), and the physics
  (``forward_solver.forces``, ``forward_solver.model``) does not import the
  compile machinery (``forward_solver.compilation``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("targets", "forward_solver", "inverse_design")
#: The marker of an allowed function-local import of the project's own code.
WORKER_MARK = "# (worker:"


def _modules() -> dict[str, Path]:
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            modules[".".join(parts).removesuffix(".__init__")] = path
    return modules


MODULES = _modules()


def _base(module: str, path: Path, node: ast.ImportFrom) -> str:
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    if not node.level:
        return node.module or ""
    parts = package.split(".")
    parts = parts[: len(parts) - node.level + 1]
    return ".".join(parts + ([node.module] if node.module else []))


def _imports():
    """``(module, imported module, name or None, node, local)`` for every import of the project's own code."""
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text())
        local = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                 for n in ast.walk(f) if isinstance(n, (ast.Import, ast.ImportFrom))}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = _base(module, path, node)
                for alias in node.names:
                    full = f"{base}.{alias.name}"
                    if full in MODULES:
                        yield module, full, None, node, id(node) in local
                    elif base in MODULES:
                        yield module, base, alias.name, node, id(node) in local
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in MODULES:
                        yield module, alias.name, None, node, id(node) in local


IMPORTS = list(_imports())


def _nested(a: str, b: str) -> bool:
    return a.startswith(b + ".") or b.startswith(a + ".")


def test_the_biaxial_fit_is_numpy_alone():
    # A fabric's test is read and fitted before any solve, to Python floats that the programs take as static
    # values: the fit imports neither JAX nor the rest of the project (the bottom of the model layer).
    folder = ROOT / "forward_solver" / "model" / "biaxial"
    imports = [node for path in sorted(folder.rglob("*.py")) for node in ast.walk(ast.parse(path.read_text()))
               if isinstance(node, (ast.Import, ast.ImportFrom))]
    names = {alias.name.split(".")[0] for node in imports if isinstance(node, ast.Import) for alias in node.names}
    names |= {node.module.split(".")[0] for node in imports if isinstance(node, ast.ImportFrom) and node.module
              and not node.level}
    assert "jax" not in names and names <= {"numpy", "csv", "hashlib", "math", "dataclasses", "pathlib", "__future__"}


def test_no_import_circle():
    graph = {m: set() for m in MODULES}
    for module, target, _, _, _ in IMPORTS:
        if target != module and not _nested(module, target):
            graph[module].add(target)
    # Tarjan's strongly connected components
    index, low, stack, on, circles, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert circles == []


def test_no_private_name_across_modules():
    private = [f"{module} <- {target}.{name}" for module, target, name, _, _ in IMPORTS
               if name and name.startswith("_") and not name.startswith("__") and target != module]
    assert private == []


def test_function_local_imports_only_for_workers():
    unmarked = []
    for module, target, _, node, local in IMPORTS:
        if not local:
            continue
        line = MODULES[module].read_text().splitlines()[node.lineno - 1]
        if WORKER_MARK not in line:
            unmarked.append(f"{MODULES[module].relative_to(ROOT)}:{node.lineno} imports {target}")
    assert unmarked == []


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


@pytest.mark.parametrize("importer, imported", [
    ("targets", "forward_solver"),
    ("targets", "inverse_design"),
    ("forward_solver", "inverse_design"),
    ("inverse_design", "inverse_design.app"),
    ("forward_solver.forces", "forward_solver.compilation"),
    ("forward_solver.model", "forward_solver.compilation"),
])
def test_data_flows_one_way(importer, imported):
    against = sorted({f"{module} -> {target}" for module, target, _, _, _ in IMPORTS
                      if _inside(module, importer) and not _inside(module, imported)
                      and _inside(target, imported)})
    assert against == []
