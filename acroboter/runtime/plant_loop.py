"""The plant's substep loop in C: a control period's RK4 substeps in one foreign call (`load_plant_loop`).

A control period holds the input for `substeps` RK4 steps of the plant (10 on the default crane). Each
step is one call of the generated `plant_step` (acroboter.codegen.plant_step); run from Python, the loop
around it (re-point the stage signals, call, compare the two event indicators, copy the state) costs
about as much as the step itself. This loop is the same statements in C, for every substep up to the
first one whose step flags a cable event: it returns that substep, the caller (Plant.advance) resolves
the event in Python as before (acroboter.sim.cable_events) and calls the loop again from the next. So
the plant's numbers are those of the Python loop to the bit: the same generated function on the same
inputs, the same comparisons (a NaN indicator is no event in either), the same copies.

The C is fixed text (acroboter/c/plant_loop.c), not generated from a spec: it takes the step as a function
pointer with CasADi's calling convention. It is compiled once into the cache like the fast path's libraries
(acroboter.runtime.compile_library: -O2 -fPIC, no fast-math, a checksum and a build key).
"""

from __future__ import annotations

import ctypes
import hashlib
from pathlib import Path

from ..model.c_templates import FOLDER
from .compile_library import ensure_built
from .fast_library import _generated, _open

NAME = "acroboter_plant_loop"

# The loop's C (acroboter/c/plant_loop.c, package data): fixed text, no placeholders.
SOURCE = (FOLDER / "plant_loop.c").read_text()

_P = ctypes.c_void_p


class LoopBuffers(ctypes.Structure):
    """struct acroboter_plant_loop."""

    _fields_ = [("step", _P), ("arg", _P), ("res", _P), ("iw", _P), ("w", _P), ("stage_slot", ctypes.c_longlong),
                ("nx", ctypes.c_longlong), ("nc", ctypes.c_longlong), ("tension_tol", ctypes.c_double),
                ("gap_tol", ctypes.c_double), ("state", _P), ("x_next", _P), ("events", _P), ("tension", _P),
                ("active", _P), ("start_tension", _P), ("start_active", _P)]


_loaded: dict[Path, object] = {}  # per cache root: the bound function, once per process


def load_plant_loop(cache_root: Path):
    """The compiled loop function `acroboter_plant_advance` (ctypes, argument types set), built on first use
    (its folder's name carries the hash of SOURCE: another version of the text is another folder) and bound once
    per process and cache."""
    if (fn := _loaded.get(cache_root)) is not None:
        return fn
    name = f"{NAME}_{hashlib.sha256(SOURCE.encode()).hexdigest()[:12]}"
    folder = cache_root / "generated" / f"fast-{name}"
    source = folder / name

    def make(target: Path) -> str:
        target.mkdir(parents=True)
        (target / f"{NAME}.c").write_text(SOURCE)
        return "1"

    _generated(name, cache_root, folder, source, make, "the plant's substep loop")
    lib_path = ensure_built(name, source, cache_root)
    fn = _open(lib_path, "the plant's substep loop library").acroboter_plant_advance
    fn.restype = ctypes.c_longlong
    fn.argtypes = [_P, _P, ctypes.c_longlong, ctypes.c_longlong, ctypes.c_longlong, ctypes.c_longlong]
    _loaded[cache_root] = fn
    return fn

