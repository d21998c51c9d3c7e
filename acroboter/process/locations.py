"""Where things live: the example specs, their checked-in generated C, and the per-user cache.

Two ways to run the package, one set of rules:

- from a source checkout (``pip install -e .``): the examples are ``model_spec/*.toml`` and their C
  is ``generated/<spec>/``, beside the package;
- installed from a wheel: the same files ship inside the package (``acroboter/examples/``, copied
  there by the wheel build), read-only.

Compiled libraries, and the C of any spec that is not a shipped example, go to a cache, never into
the package: in a checkout its ``build/cache/`` (what ``make build`` fills, so ``.venv/bin/acroboter``
finds the libraries ``make`` compiled), installed the per-user cache
(``platformdirs.user_cache_dir("acroboter")``); ``ACROBOTER_CACHE_DIR`` or the CLIs' ``--cache-dir``
move it.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # acroboter/ (this file is acroboter/process/locations.py)
CACHE_ENV = "ACROBOTER_CACHE_DIR"
_PACKAGED = PACKAGE_DIR / "examples"  # only in an installed wheel


def checkout_root() -> Path | None:
    """The source checkout the package runs from, or None when it is installed."""
    root = PACKAGE_DIR.parent
    if (root / "model_spec").is_dir() and (root / "pyproject.toml").is_file():
        return root
    return None


def spec_folder() -> Path:
    """The folder of the example specs (model_spec/ in a checkout)."""
    root = checkout_root()
    return root / "model_spec" if root is not None else _PACKAGED / "specs"


def shipped_generated_folder() -> Path:
    """The checked-in (or packaged) generated C of the example specs, one folder per spec."""
    root = checkout_root()
    return root / "generated" if root is not None else _PACKAGED / "generated"


def example_names() -> list[str]:
    """The names of the example cranes: ``acroboter`` (the paper's), ``acroboter_4cable``, ..."""
    return sorted(p.stem for p in spec_folder().glob("*.toml"))


def example_spec(name: str = "acroboter") -> Path:
    """The path of an example spec by name, e.g. ``acroboter.example_spec("acroboter_4cable")``.

    Copy it to model a crane of your own (give the copy a name of its own)."""
    path = spec_folder() / f"{name}.toml"
    if not path.is_file():
        raise FileNotFoundError(f"no example spec '{name}': the examples are {', '.join(example_names())}")
    return path


def cache_dir(override: str | os.PathLike | None = None) -> Path:
    """The cache for compiled libraries and generated C: `override`, else $ACROBOTER_CACHE_DIR, else
    the checkout's build/cache/ when running from one, else the per-user cache folder of the platform
    (~/.cache/acroboter on Linux)."""
    if override is not None:
        return Path(override).expanduser().resolve()
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser().resolve()
    root = checkout_root()
    if root is not None:
        return root / "build" / "cache"
    import platformdirs

    return Path(platformdirs.user_cache_dir("acroboter", appauthor=False))
