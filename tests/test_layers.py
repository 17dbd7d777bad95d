"""The package's import graph: no cycle, and every import goes down the layers of
ARCHITECTURE.md (peers such as ``ortho`` and ``mvp`` never import each other)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "orthomvp"

LAYERS = [
    ("orthomvp._lazy", "orthomvp._moved"),
    ("orthomvp", "orthomvp.errors"),
    (
        "orthomvp.codes",
        "orthomvp.optional",
        "orthomvp.io",
        "orthomvp.io.preflight",
        "orthomvp.io.signals",
        "orthomvp.validate",
        "orthomvp.geometry",
        "orthomvp.geometry.vectors",
        "orthomvp.geometry.crs",
        "orthomvp.geometry.normals",
        "orthomvp.geometry.heights",
        "orthomvp.jit",
    ),
    ("orthomvp.io.files", "orthomvp.io.output_checks"),
    ("orthomvp.io.write_errors",),
    ("orthomvp.io.outputs", "orthomvp.io.isis"),
    ("orthomvp.io.raster",),
    ("orthomvp.geometry.datum",),
    ("orthomvp.geometry.terrain",),
    ("orthomvp.geometry.world", "orthomvp.camera"),
    ("orthomvp.occlusion", "orthomvp.occlusion.mesh", "orthomvp.occlusion.embree"),
    (
        "orthomvp.occlusion.raycast",
        "orthomvp.occlusion.post_geometry",
        "orthomvp.occlusion.post_lattice_kernel",
    ),
    (
        "orthomvp.occlusion.post_geometry_kernel",
        "orthomvp.occlusion.post_lattice",
        "orthomvp.occlusion.occluders",
        "orthomvp.occlusion.carry",
    ),
    ("orthomvp.occlusion.paths",),
    (
        "orthomvp.occlusion.visibility",
        "orthomvp.ortho",
        "orthomvp.ortho.composite_kernel",
        "orthomvp.ortho.balance",
    ),
    ("orthomvp.ortho.composite",),
    ("orthomvp.ortho.orthophoto", "orthomvp.mvp"),
    ("orthomvp.engine", "orthomvp.explore", "orthomvp.synthetic"),
    ("orthomvp.present",),
    ("orthomvp.quality",),
    ("orthomvp.view",),
    ("orthomvp.bench", "orthomvp.demo"),
    ("orthomvp.cli",),
    ("orthomvp._entry",),
    ("orthomvp.__main__",),
]
"""Bottom to top; a module may import from lower layers and from its own unit only."""


def _module(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _group(module: str) -> tuple[int, str]:
    """(layer, top-level unit) of a module: the longest prefix listed in LAYERS."""
    best = None
    for layer, names in enumerate(LAYERS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and (
                best is None or len(name) > len(best[1])
            ):
                best = (layer, name)
    assert best is not None, f"{module} is in no layer of this test"
    return best


def _runtime_nodes(tree: ast.AST) -> list[ast.AST]:
    """All nodes of ``tree`` outside ``if TYPE_CHECKING:`` blocks (annotations only)."""
    out, todo = [], [tree]
    while todo:
        node = todo.pop()
        out.append(node)
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))
    return out


def _imports(typing: bool = False) -> dict[str, set[str]]:
    """Every orthomvp module and the orthomvp modules it imports (anywhere in the file; with
    ``typing``, also in ``if TYPE_CHECKING:`` blocks). ``from package import submodule``
    imports the submodule, as ``import package.submodule`` does, not the package's names."""
    paths = list(PACKAGE.rglob("*.py"))
    modules = {_module(path) for path in paths}
    graph: dict[str, set[str]] = {}
    for path in paths:
        name = _module(path)
        base = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree) if typing else _runtime_nodes(tree):
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name.startswith("orthomvp")}
            elif isinstance(node, ast.ImportFrom):
                mod = node.module or ""
                if node.level:
                    anchor = base.split(".")[: len(base.split(".")) - node.level + 1]
                    mod = ".".join([*anchor, mod] if mod else anchor)
                if mod.startswith("orthomvp"):
                    names = {f"{mod}.{a.name}" for a in node.names}
                    deps |= names if names <= modules else {mod, *names}
        graph[name] = deps
    return {k: {d for d in v if d in graph and d != k} for k, v in graph.items()}


def test_no_import_cycle() -> None:
    """Not even through the imports for type annotations alone."""
    graph = _imports(typing=True)
    state: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                cycle = stack[stack.index(dep) :] + [dep] if dep in stack else [node, dep]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if dep not in state:
                visit(dep, [*stack, dep])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])


def test_imports_go_down_the_layers() -> None:
    bad = []
    for module, deps in _imports().items():
        layer, unit = _group(module)
        for dep in deps:
            dep_layer, dep_unit = _group(dep)
            if dep_layer > layer or (dep_layer == layer and dep_unit != unit):
                bad.append(f"{module} imports {dep}")
    assert not bad, "upward or sideways imports: " + "; ".join(sorted(bad))


def test_cube_camera_reader() -> None:
    """The cube camera reader (orthomvp.camera.isis: shared core, tables, times and isd
    modules, and one module per instrument) builds on the CSM models and the cube label reader
    only, and the camera registry imports it (and pvl) only when a cube is read."""
    import subprocess
    import sys

    graph = _imports()
    reader = {
        m for m in graph if m == "orthomvp.camera.isis" or m.startswith("orthomvp.camera.isis.")
    }
    shared = {"core", "tables", "times", "isd"}
    assert {f"orthomvp.camera.isis.{m}" for m in [*shared, "lro_nac"]} <= reader
    for module in reader:
        outside = {d for d in graph[module] if d not in reader and d != "orthomvp.errors"}
        assert all(
            d.startswith("orthomvp.camera.csm") or d == "orthomvp.io.isis" for d in outside
        ), f"{module} imports {sorted(outside)}"
    code = (
        "import sys, orthomvp.camera; "
        "print('orthomvp.camera.isis' in sys.modules, 'pvl' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
