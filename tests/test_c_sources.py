"""C as C (issue 35 item 4): the package's hand-written C lives in acroboter/c/ as .c and .h files. A file
with no placeholder compiles on its own without a warning under -Wall -Wextra -Werror (at the build's -O2 -fPIC);
the templates compile so once filled in (tests/test_fail_safe.py: the stateful controller with and without an
estimator, the path, the state size). No Python module carries C source text."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

from acroboter.model.c_templates import FOLDER

PACKAGE = Path(__file__).resolve().parent.parent / "acroboter"
PLACEHOLDER = re.compile(r"@[A-Z][A-Z0-9_]*@")


@pytest.mark.parametrize("source", sorted(p.name for p in FOLDER.glob("*.c")))
def test_each_plain_c_file_compiles_without_a_warning(source, tmp_path):
    text = (FOLDER / source).read_text()
    if PLACEHOLDER.search(text):
        pytest.skip(f"{source} is a template: compiled filled in (tests/test_fail_safe.py)")
    done = subprocess.run([os.environ.get("CC", "cc"), "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-c",
                           str(FOLDER / source), "-o", str(tmp_path / "out.o")], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_no_python_module_carries_c_source():
    markers = re.compile(r"^\s*#include\s*[<\"]|^\s*(?:static\s+)?(?:int|void|double)\s+\w+\s*\([^)]*\)\s*\{", re.M)
    found = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if markers.search(p.read_text())}
    assert not found, f"C source text in Python strings: {sorted(found)} (put it in acroboter/c/)"
