"""Imports go one way: spec model -> code generation -> compiled bindings -> controllers and plant
-> simulation -> the library face -> studies, reports and CLIs. Read from the source with `ast`
(every import, also those inside functions), so a new upward import fails here, not in review."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "acroboter"

# Lowest first. A module may import its own layer and the layers below, never above.
LAYERS = [
    ("model", {"spec", "layout", "interrupts", "fingerprint", "settings", "locations", "physical", "mjcf_model"}),
    ("codegen", {"codegen"}),  # the subpackage acroboter.codegen
    ("bindings", {"build", "compiled"}),
    ("store", {"cache", "casadi_backend"}),  # the only runtime modules that may call the code generator
    ("control", {"path", "recovery", "distribution", "controllers", "plant", "mujoco_plant", "statics", "sensing"}),
    ("simulation", {"simulation", "feasibility", "result", "open_loop"}),
    ("api", {"crane"}),
]
TOP = "studies, reports and CLIs"  # every other module
ORDER = [name for name, _ in LAYERS] + [TOP]
# Besides the order: the code generator and the runtime know nothing of each other.
NO_CODEGEN = {"bindings", "control", "simulation"}


def layer_of(module: str) -> str:
    head = module.split(".")[1] if module.count(".") else "__init__"
    for name, members in LAYERS:
        if head in members:
            return name
    return TOP


def modules() -> dict[str, Path]:
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
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


@pytest.mark.parametrize("module", sorted(ALL))
def test_imports_go_one_way(module):
    mine = layer_of(module)
    for target in sorted(imports_of(module, ALL[module], set(ALL))):
        theirs = layer_of(target)
        assert ORDER.index(theirs) <= ORDER.index(mine), (
            f"{module} ({mine}) imports {target} ({theirs}), a layer above it")
        if mine == "codegen":
            assert theirs in ("model", "codegen"), f"the code generator {module} imports {target} ({theirs})"
        if mine in NO_CODEGEN:
            assert theirs != "codegen", f"the runtime module {module} imports the code generator ({target})"


def test_the_rule_sees_a_violation(tmp_path):
    """The checker itself: an upward import and a runtime -> codegen import are found."""
    bad = tmp_path / "controllers.py"
    bad.write_text("from .codegen.generate import generate\ndef f():\n    from .crane import Crane\n")
    found = imports_of("acroboter.controllers", bad, set(ALL))
    assert {"acroboter.codegen.generate", "acroboter.crane"} <= found
    assert layer_of("acroboter.codegen.generate") == "codegen" and layer_of("acroboter.crane") == "api"
