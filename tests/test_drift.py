"""Drift cannot come back (issue 35 item 6): every `acroboter.x.y` in the docs, the README, the package's docstrings
and comments, the C templates, the generated C and the tools resolves to a module or an attribute; the README's
layer row names every layer folder; the architecture page's tools row names every file in tools/; the README's test
count is the suite's."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path

from test_import_layers import LAYERS

REPO = Path(__file__).resolve().parent.parent
DOTTED = re.compile(r"\bacroboter(?:\.[A-Za-z_][A-Za-z_0-9]*)+")
# Not names of code: file names (acroboter.toml, .gif, ...) and the mutation tool's mutant patterns.
FILE_SUFFIXES = ("toml", "gif", "xml", "json", "csv", "mp4", "png", "c", "h", "so", "md", "txt")
NOT_CODE = re.compile(r"xǁ|__mutmut_|no_such_mutant")


def _sources() -> list[Path]:
    found = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md")), *sorted((REPO / "acroboter").rglob("*.py")),
             *sorted((REPO / "acroboter" / "c").iterdir()), *sorted((REPO / "tools").iterdir()),
             *sorted((REPO / "generated").rglob("*.c"))]
    return [p for p in found if p.is_file()]


def _resolves(name: str) -> bool:
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for part in parts[i:]:
            if not hasattr(obj, part):
                return False
            obj = getattr(obj, part)
        return True
    return False


def test_every_dotted_name_resolves():
    unresolved = {}
    for path in _sources():
        text = path.read_text(errors="ignore")
        for match in DOTTED.finditer(text):
            name = match.group(0)
            tail = text[match.end() : match.end() + 2]
            if name.rsplit(".", 1)[1] in FILE_SUFFIXES or NOT_CODE.search(text[match.start() : match.end() + 3]):
                continue
            if tail.startswith("ǁ"):
                continue
            if not _resolves(name):
                unresolved.setdefault(name, set()).add(str(path.relative_to(REPO)))
    assert not unresolved, "\n".join(f"{name}: {sorted(where)}" for name, where in sorted(unresolved.items()))


def test_the_readme_layer_row_names_every_layer():
    row = next(line for line in (REPO / "README.md").read_text().splitlines() if line.startswith("| `acroboter/` |"))
    named = re.findall(r"`([a-z_]+)/`", row.split("|")[2])
    assert sorted(named) == sorted(LAYERS), f"README's acroboter/ row names {named}; the layers are {LAYERS}"
    assert named == LAYERS[::-1], "README's acroboter/ row: the layers top to bottom"


def test_the_tools_row_names_every_tool():
    row = next(line for line in (REPO / "docs" / "architecture.md").read_text().splitlines()
               if line.startswith("| `tools/` |"))
    named = set(re.findall(r"`([A-Za-z_0-9.]+\.(?:py|toml))`", row))
    present = {p.name for p in (REPO / "tools").iterdir() if p.suffix in (".py", ".toml")}
    assert named == present, f"docs/architecture.md tools row: not named {sorted(present - named)}, " \
                             f"named but absent {sorted(named - present)}"


_COLLECTED: list[str] = []


def collected() -> list[str]:
    """Every test's node id, as `pytest --collect-only -q` from the repository's root lists them (once)."""
    if not _COLLECTED:
        done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                               "tests"], capture_output=True, text=True, cwd=REPO, timeout=600)
        _COLLECTED.extend(line for line in done.stdout.splitlines() if "::" in line)
        assert int(re.search(r"(\d+) tests? collected", done.stdout).group(1)) == len(_COLLECTED)
    return _COLLECTED


def test_the_readme_test_count_is_the_suites():
    collected_count = len(collected())
    stated = re.search(r"ruff, ([\d,]+) tests on two pytest-xdist workers", (REPO / "README.md").read_text())
    assert stated is not None, "README.md: the `make test` sentence with its test count"
    assert int(stated.group(1).replace(",", "")) == collected_count, \
        f"README.md says {stated.group(1)} tests; the suite collects {collected_count}: measure and say so"


def test_every_test_left_to_make_test_long_exists():
    """tests/long_tests.txt names tests by node id: a renamed or removed one would no longer be marked and would
    run in `make test` again, unnoticed; each listed id is a collected test (or, without parameters, a collected
    test's function) and names the sample `make test` keeps."""
    from conftest import long_tests

    listed, ids = long_tests(), set(collected())
    assert listed
    functions = {node.split("[")[0] for node in ids}
    for node, sample in listed.items():
        assert node in ids or ("[" not in node and node in functions), f"{node}: no such test"
        assert sample, f"{node}: say which sample make test keeps"
