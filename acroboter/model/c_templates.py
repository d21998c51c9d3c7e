"""Hand-written C lives as C (acroboter/c/*.c, *.h: package data), filled in here: `render` replaces each
@KEY@ with its value and refuses a template left with a placeholder, so a C tool, an editor and the compiler's
warnings (tests/test_c_sources.py: -Wall -Wextra -Werror) see the real text."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

FOLDER = Path(__file__).resolve().parent.parent / "c"  # acroboter/c/: package data
_PLACEHOLDER = re.compile(r"@[A-Z][A-Z0-9_]*@")

__all__ = ["FOLDER", "render", "templates_digest"]


def render(name: str, **values: object) -> str:
    """The template `name` (a file in acroboter/c/) with @KEY@ replaced by str(values[KEY])."""
    text = (FOLDER / name).read_text()
    for key, value in values.items():
        text = text.replace(f"@{key}@", str(value))
    left = sorted(set(_PLACEHOLDER.findall(text)))
    if left:
        raise KeyError(f"template {name}: no value for {', '.join(left)}")
    return text


def templates_digest() -> bytes:
    """A digest of every template's bytes: part of the key of whatever is generated from them."""
    h = hashlib.sha256()
    for path in sorted(FOLDER.iterdir()):
        if path.suffix in (".c", ".h"):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.digest()
