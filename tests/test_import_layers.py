"""The package's layers are its folders, and imports go one way: down. Read from the source with `ast`
(every import, also those inside functions), so a new upward import fails here, not in review.

The order is declared once, in LAYERS below; the layer table of docs/architecture.md is checked against
it (every folder in this order, every module named), so it cannot drift from the tree.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / "acroboter"

# The folders of acroboter/, lowest first. A module may import its own folder and the folders below, never
# one above. Each folder's __init__.py says in one sentence what it holds.
LAYERS = ["process", "model", "codegen", "runtime", "control", "sim", "planning", "api", "studies", "report", "cli"]
# acroboter/ itself holds only the public face and forwarding modules (above every layer): __init__.py
# (acroboter.Crane, ... loaded on first use), __main__.py (`python -m acroboter`) and one module per
# `python -m acroboter.<command>` form, each a forward to the command's module.
TOP = "top"
TOP_MODULES = {"__init__", "__main__", "run", "bench", "study", "sweep", "robustness", "build", "animate", "mjcf",
               "plant_fuzz", "plan"}
ORDER = [*LAYERS, TOP]
# Besides the order (which leaves the code generator only the model below it): of the runtime only these
# two modules may call the code generator; the rest of it, control and sim never import it.
MAY_GENERATE = {"acroboter.runtime.cache", "acroboter.runtime.casadi_backend", "acroboter.runtime.fast_library"}
NO_CODEGEN = {"runtime", "control", "sim"}
# A module is read in one sitting: at most this many lines, unless listed here with the reason.
MAX_LINES = 500
OVERSIZE: dict[str, str] = {}


def layer_of(module: str) -> str:
    parts = module.split(".")
    if len(parts) >= 3 or (len(parts) == 2 and parts[1] in LAYERS):
        return parts[1]
    return TOP


def modules() -> dict[str, Path]:
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        if "examples" in path.relative_to(PACKAGE).parts:  # the wheel's copied example files
            continue
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports_of(module: str, path: Path, known: set[str]) -> set[str]:
    """The package modules `module` imports (absolute or relative, at any depth in the file)."""
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.split(".")[0] == "acroboter"}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "acroboter":
                continue
            found.add(target)
            for alias in node.names:  # `from . import plant` imports a module
                if f"{target}.{alias.name}" in known:
                    found.add(f"{target}.{alias.name}")
    return {m for m in found if m in known and m != "acroboter"}


ALL = modules()


def check(module: str, target: str) -> str | None:
    """Why `module` may not import `target` (None: it may)."""
    mine, theirs = layer_of(module), layer_of(target)
    if ORDER.index(theirs) > ORDER.index(mine):
        return f"{module} ({mine}/) imports {target} ({theirs}/), a layer above it"
    if mine in NO_CODEGEN and theirs == "codegen" and module not in MAY_GENERATE:
        return f"the runtime module {module} imports the code generator ({target})"
    return None


@pytest.mark.parametrize("module", sorted(ALL))
def test_imports_go_one_way(module):
    for target in sorted(imports_of(module, ALL[module], set(ALL))):
        problem = check(module, target)
        assert problem is None, problem


def test_the_rule_sees_a_violation(tmp_path):
    """The checker itself: an upward import and a runtime -> codegen import are found and refused."""
    bad = tmp_path / "controllers.py"
    bad.write_text("from ..codegen.emit_c import generate\ndef f():\n    from ..api.crane import Crane\n")
    found = imports_of("acroboter.control.controllers", bad, set(ALL))
    assert {"acroboter.codegen.emit_c", "acroboter.api.crane"} <= found
    assert layer_of("acroboter.codegen.emit_c") == "codegen" and layer_of("acroboter.api.crane") == "api"
    assert "a layer above it" in check("acroboter.control.controllers", "acroboter.api.crane")
    assert "code generator" in check("acroboter.control.controllers", "acroboter.codegen.emit_c")
    assert "code generator" in check("acroboter.runtime.compiled", "acroboter.codegen.emit_c")
    assert check("acroboter.runtime.cache", "acroboter.codegen.emit_c") is None
    assert "a layer above it" in check("acroboter.codegen.symbolic", "acroboter.runtime.compiled")
    assert check("acroboter.cli.run", "acroboter.model.spec") is None


def test_every_folder_is_a_layer_and_the_top_holds_only_forwards():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert folders == set(LAYERS), f"folders that are no layer: {folders ^ set(LAYERS)}"
    top = {p.stem for p in PACKAGE.glob("*.py")}
    assert top == TOP_MODULES, f"modules at the top of acroboter/ that are not declared: {top ^ TOP_MODULES}"
    for name in TOP_MODULES - {"__init__"}:
        assert len((PACKAGE / f"{name}.py").read_text().splitlines()) <= 10, f"acroboter/{name}.py is no forward"


def test_no_import_cycle_between_files():
    graph = {m: imports_of(m, p, set(ALL)) for m, p in ALL.items()}
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(graph[module]):
            assert state.get(target) != 1, "import cycle: " + " -> ".join([*path[path.index(target):], target])
            if target not in state:
                visit(target, [*path, target])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])


@pytest.mark.parametrize("module", sorted(ALL))
def test_a_module_is_read_in_one_sitting(module):
    lines = len(ALL[module].read_text().splitlines())
    assert lines <= MAX_LINES or module in OVERSIZE, f"{module}: {lines} lines (> {MAX_LINES}) and no reason given"


def _layer_rows(text: str) -> list[tuple[str, str]]:
    """(folder, rest of the row) of each row of the document's layer table (headed `| folder | modules |`)."""
    table = text[text.index("| folder | modules |"):].split("\n\n", 1)[0]
    return re.findall(r"^\| `(\w+)/` \|(.*)$", table, flags=re.M)


def _named(row: str) -> set[str]:
    return set(re.findall(r"`([\w/]+)\.py`", row))


def _folder_modules(folder: str) -> set[str]:
    root = PACKAGE / folder
    return {str(p.relative_to(root).with_suffix("")) for p in root.rglob("*.py") if p.name != "__init__.py"}


@pytest.mark.parametrize("document", ["docs/architecture.md"])
def test_the_documented_layout_is_the_tree(document):
    """The document's layer table lists the folders top to bottom and names every module of each one (the
    README keeps a short summary of the folders and points here)."""
    rows = _layer_rows((REPO / document).read_text())
    assert [folder for folder, _ in rows] == LAYERS[::-1], f"{document}: the layers, top to bottom, are {LAYERS[::-1]}"
    for folder, row in rows:
        modules_here = _folder_modules(folder)
        named = _named(row)
        assert named == modules_here, (f"{document}, {folder}/: not named {sorted(modules_here - named)}, "
                                       f"named but absent {sorted(named - modules_here)}")
