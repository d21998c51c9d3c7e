/* acroboter's plant substep loop (acroboter/runtime/plant_loop.py): what Plant.advance's Python loop does,
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
