"""The plant's substep loop in C: a control period's RK4 substeps in one foreign call (`load_plant_loop`).

A control period holds the input for `substeps` RK4 steps of the plant (10 on the default crane). Each
step is one call of the generated `plant_step` (acroboter.codegen.plant); run from Python, the loop
around it (re-point the stage signals, call, compare the two event indicators, copy the state) costs
about as much as the step itself. This loop is the same statements in C, for every substep up to the
first one whose step flags a cable event: it returns that substep, the caller (Plant.advance) resolves
the event in Python as before (acroboter.sim.cable_events) and calls the loop again from the next. So
the plant's numbers are those of the Python loop to the bit: the same generated function on the same
inputs, the same comparisons (a NaN indicator is no event in either), the same copies.

The C is fixed text (below), not generated from a spec: it takes the step as a function pointer with
CasADi's calling convention. It is compiled once into the cache like the fast path's libraries
(acroboter.runtime.build: -O2 -fPIC, no fast-math, a checksum and a build key).
"""

from __future__ import annotations

import ctypes
import hashlib
from pathlib import Path

from .build import ensure_built
from .fast_library import _generated, _open

NAME = "acroboter_plant_loop"

SOURCE = r"""/* acroboter's plant substep loop (acroboter/runtime/plant_loop.py): what Plant.advance's Python loop does,
   for the substeps up to the first one with a cable event. No heap, no libm. */
#include <string.h>

typedef long long casadi_int;
typedef int (*plant_step_fn)(const double** arg, double** res, casadi_int* iw, double* w, int mem);

/* The buffers of one bound plant step (acroboter.runtime.compiled.BoundFunction), set once per plant. */
struct acroboter_plant_loop {
  plant_step_fn step;
  const double** arg;      /* the step's argument slots: slot `stage_slot` is re-pointed per substep */
  double** res;
  casadi_int* iw;
  double* w;
  casadi_int stage_slot;
  casadi_int nx;           /* length of x = [q, qd, W_u, W_anchor, E_d] */
  casadi_int nc;           /* cables */
  double tension_tol;      /* N: a taut cable pushing by more is an event */
  double gap_tol;          /* m: a slack cable stretched by more is an event */
  double* state;           /* the step's input x, advanced in place */
  const double* x_next;    /* the step's output x(t + h) */
  const double* events;    /* [max push over taut cables, max stretch over slack cables] */
  const double* tension;   /* per cable at the start of the step */
  const double* active;    /* the cable mask the step read */
  double* start_tension;   /* recorded at substep `record_at` */
  double* start_active;
};

/* Substeps from .. end - 1 of the period whose stage signals start at `stage` (rows of `row_bytes`
   bytes, substep i reads rows 2i .. 2i + 2). Returns the first substep whose step flags an event
   (its x is not taken: the caller resolves it), `end` when none did, -1 when the step failed. */
casadi_int acroboter_plant_advance(struct acroboter_plant_loop* loop, const char* stage, casadi_int row_bytes,
                                   casadi_int from, casadi_int end, casadi_int record_at) {
  casadi_int i;
  for (i = from; i < end; ++i) {
    loop->arg[loop->stage_slot] = (const double*) (stage + 2 * i * row_bytes);
    if (loop->step(loop->arg, loop->res, loop->iw, loop->w, 0) != 0) return -1;
    if (loop->events[0] > loop->tension_tol || loop->events[1] > loop->gap_tol) return i;
    if (i == record_at) {
      memcpy(loop->start_tension, loop->tension, (size_t) loop->nc * sizeof(double));
      memcpy(loop->start_active, loop->active, (size_t) loop->nc * sizeof(double));
    }
    memcpy(loop->state, loop->x_next, (size_t) loop->nx * sizeof(double));
  }
  return end;
}
"""

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

