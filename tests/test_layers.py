"""The layers of docs/architecture.md hold in the code: a package imports only the packages listed
before it (utils/, runfolder/, errors and version from anywhere; runfolder/ only those three), a room
of evaluation/ only the rooms before it, and no module imports itself back through others, whether
at the top of a file or inside a function."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "metadagger"
#: docs/architecture.md's layers, lowest first.
LAYERS = (
    "tasks",
    "policies",
    "imitation",
    "metal_dagger",
    "mapping",
    "evaluation",
    "pipeline",
    "results",
    "label",
    "cli",
)
#: What any layer may import.
ANYWHERE = {"utils", "runfolder", "errors", "version"}
#: The rooms of evaluation/, lowest first; a room reads only the rows before its own.
ROOMS = (
    {"rows", "paired", "curves"},
    {"mdm", "mdi", "diagnose", "expert", "tensorboard"},
    {"benchmark"},
    {"video"},
    {"report"},
)


def _module_name(path: Path) -> str:
    parts = ["metadagger", *path.relative_to(PACKAGE).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(tree: ast.AST) -> list[str]:
    """The ``metadagger`` modules a file imports at run time (``if TYPE_CHECKING:`` blocks left
    out: they are read by type checkers only), as written: ``from a.b import c`` gives ``a.b.c``,
    which :func:`_resolve` shortens to the module it names."""
    found: list[str] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            return
        if isinstance(node, ast.Import):
            found.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.extend(f"{node.module}.{alias.name}" for alias in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return [name for name in found if name.split(".")[0] == "metadagger"]


def _graph() -> dict[str, set[str]]:
    """Every module of the package and the package modules it imports."""
    files = {_module_name(path): path for path in PACKAGE.rglob("*.py")}

    def resolve(name: str) -> str:
        while name not in files:
            name = name.rpartition(".")[0]
        return name

    return {
        module: {resolve(name) for name in _imports(ast.parse(path.read_text()))} - {module}
        for module, path in files.items()
    }


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_every_package_imports_only_the_layers_below_it():
    graph = _graph()
    assert {_layer(m) for m in graph} - {""} == set(LAYERS) | ANYWHERE, "a new package: add it to docs/architecture.md"
    wrong = []
    for module, targets in graph.items():
        layer = _layer(module)
        if layer == "":  # the package's own __init__: the public API, above every layer
            continue
        for target in targets:
            other = _layer(target)
            if other == layer:
                continue
            if layer == "runfolder":
                allowed = other in ANYWHERE
            elif layer in ANYWHERE:
                allowed = other in ANYWHERE - {"runfolder"}
            else:
                allowed = other in ANYWHERE or (other in LAYERS and LAYERS.index(other) < LAYERS.index(layer))
            if not allowed:
                wrong.append(f"{module} imports {target}")
    assert not wrong, wrong


def test_each_room_of_the_evaluation_layer_reads_only_the_rooms_above_it():
    rank = {room: level for level, rooms in enumerate(ROOMS) for room in rooms}
    evaluation = {m: t for m, t in _graph().items() if _layer(m) == "evaluation" and m.count(".") >= 2}
    assert {m.split(".")[2] for m in evaluation} == set(rank), "a new room: add it to docs/architecture.md"
    wrong = [
        f"{module} imports {target}"
        for module, targets in evaluation.items()
        for target in targets
        if _layer(target) == "evaluation"
        and target.count(".") >= 2
        and target.split(".")[2] != module.split(".")[2]
        and rank[target.split(".")[2]] >= rank[module.split(".")[2]]
    ]
    assert not wrong, wrong


def test_no_module_imports_itself_back():
    graph = _graph()
    done: set[str] = set()

    def visit(module: str, path: list[str]) -> None:
        if module in path:
            raise AssertionError("a circle: " + " -> ".join(path[path.index(module) :] + [module]))
        if module in done:
            return
        for target in sorted(graph[module]):
            visit(target, path + [module])
        done.add(module)

    for module in sorted(graph):
        visit(module, [])
