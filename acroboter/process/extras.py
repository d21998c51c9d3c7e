"""The optional extras, and the one check every command and call makes before it needs one (docs/extras.md).

`pip install acroboter` is the core (CORE below): the controllers, the own plant, every figure and summary, the
code generator and the compiled libraries. What needs more is an extra:

    mujoco     MuJoCo: run --plant mujoco and --view, animate --renderer mujoco, mjcf, plant-fuzz,
               Crane.simulate(plant="mujoco"), MujocoPlant
    animation  imageio with its ffmpeg binary: animate's MP4 (a GIF needs neither: Pillow comes with matplotlib)
    dask       dask.distributed: sweep, robustness on a cluster, plant-fuzz on more than one worker

`require(extra, what)` looks each package of the extra up with importlib.util.find_spec (no import: cheap, and
mujoco picks its GL backend when first imported) and raises MissingExtraError, an ImportError whose message is
one line ending in the `pip install` that fixes it; the command lines turn it into exit 2 before any work.
`missing_core()` does the same for the core dependencies (a broken install): the console's one line, exit 3.
"""

from __future__ import annotations

import importlib.util

from .locations import checkout_root

# extra -> the modules it provides (what find_spec looks for), in the order they are named when missing
EXTRAS: dict[str, tuple[str, ...]] = {
    "mujoco": ("mujoco",),
    "animation": ("imageio", "imageio_ffmpeg"),
    "dask": ("dask", "distributed"),
}
# The core dependencies: module -> distribution (pyproject's [project] dependencies; tests/test_extras.py
# holds the two lists equal).
CORE: dict[str, str] = {
    "casadi": "casadi",
    "numpy": "numpy",
    "scipy": "scipy",
    "matplotlib": "matplotlib",
    "PIL": "pillow",
    "pydantic": "pydantic",
    "tqdm": "tqdm",
    "platformdirs": "platformdirs",
    "daqp": "daqp",
}


def install_line(extra: str) -> str:
    return f"pip install 'acroboter[{extra}]'"


def _in_checkout() -> str:
    return " (in this checkout: make setup)" if checkout_root() is not None else ""


class MissingExtraError(ImportError):
    """An optional extra is not installed: `what` needs it. The message names the extra, the missing package
    and the one `pip install` line that fixes it (bad input for a command line: exit 2)."""

    def __init__(self, extra: str, package: str, what: str, hint: str | None = None):
        self.extra, self.package, self.what = extra, package, what
        why = f"{package} is not installed" + (f"; {hint}" if hint else "")
        super().__init__(f"{what} needs the {extra} extra ({why}): {install_line(extra)}{_in_checkout()}",
                         name=package)


def _found(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a parent that does not import, or a module without a spec
        return False


def missing(extra: str) -> str | None:
    """The first package of `extra` that is not installed (None: all are)."""
    if extra not in EXTRAS:
        raise ValueError(f"unknown extra {extra!r}: one of {', '.join(EXTRAS)}")
    return next((module for module in EXTRAS[extra] if not _found(module)), None)


def require(extra: str, what: str, hint: str | None = None) -> None:
    """Raise MissingExtraError unless every package of `extra` is installed; `what` is what needs it, as the
    user asked for it ("--plant mujoco"); `hint` a way around it that needs no extra."""
    package = missing(extra)
    if package is not None:
        raise MissingExtraError(extra, package, what, hint)


def core_line(module: str) -> str:
    """The one line for a core dependency that is missing or does not import (`module`: its import name)."""
    dist = CORE.get(module, module)
    return (f"the core dependency {dist} is not installed (or does not import): "
            f"pip install '{_requirement(dist)}'{_in_checkout()}")


def missing_core() -> str | None:
    """core_line of the first core dependency that is not installed (None: all are); find_spec only."""
    module = next((m for m in CORE if not _found(m)), None)
    return None if module is None else core_line(module)


def is_core(module: str | None) -> bool:
    """Whether the module (a dotted name, as ImportError.name gives it) belongs to a core dependency."""
    return module is not None and module.split(".")[0] in CORE


def _requirement(dist: str) -> str:
    """The requirement of the installed acroboter on `dist` (e.g. scipy>=1.11), else the bare name."""
    from importlib import metadata

    try:
        requires = metadata.requires("acroboter") or []
    except metadata.PackageNotFoundError:
        requires = []
    for text in requires:
        if ";" in text:  # an extra's
            continue
        name = text.split("[")[0]
        for stop in "<>=!~ ":
            name = name.split(stop)[0]
        if name.strip().lower().replace("_", "-") == dist:
            return text.replace(" ", "")
    return dist
