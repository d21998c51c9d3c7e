/* @NAME@: the stateful controller (see @NAME@.h). Generated from acroboter/c/controller.c by
 * `acroboter export-step --stateful`: do not edit, re-export. acroboter.sim.stateful_controller.StatefulController is the
 * same step in Python, statement for statement. */
#include <math.h>
#include "@NAME@.h"

@DEFINES@
@ESTIMATOR_CODE@
@PATH_CODE@
/* u finite and inside the limits and the sanity bound (to COMMAND_TOLERANCE of each bound). */
static int command_within(const double* u) {
  casadi_int i;
  for (i = 0; i < L; ++i)
    if (!isfinite(u[i]) || !(u[i] >= @NAME@_u_low[i] - COMMAND_TOLERANCE * fmax(1.0, fabs(@NAME@_u_low[i]))) ||
        !(u[i] <= @NAME@_u_high[i] + COMMAND_TOLERANCE * fmax(1.0, fabs(@NAME@_u_high[i]))))
      return 0;
  return 1;
}

/* core(q, qd, signals, z) into u_core, qdd and saturated; non-zero if it failed. */
static int core(@NAME@_state* st, const double* q, const double* qd, const double* signals, const double* z) {
  st->arg[0] = q;
  st->arg[1] = qd;
  st->arg[2] = signals;
  st->arg[3] = signals + NS;
  st->arg[4] = signals + 2 * NS;
  st->arg[5] = z;
  st->res[0] = st->u_core;
  st->res[1] = st->qdd;
  st->res[2] = &st->saturated;
  return @NAME@_core(st->arg, st->res, st->iw, st->w, 0);
}

/* q0 a state of the crane: finite, every body's (u, v, w) right-handed orthonormal, phi(q0) = 0 (INIT_TOLERANCE). */
static int start_valid(@NAME@_state* st, const double* q0, const double* signals) {
  casadi_int i, b;
  double worst = 0.0;
  for (i = 0; i < N; ++i)
    if (!isfinite(q0[i])) return 0;
  for (b = 0; b < NB; ++b) {
    const double *u = q0 + bodies[b] + 3, *v = u + 3, *w = u + 6;
    const double triple = (u[1] * v[2] - u[2] * v[1]) * w[0] + (u[2] * v[0] - u[0] * v[2]) * w[1] +
                          (u[0] * v[1] - u[1] * v[0]) * w[2];
    if (!(fabs(triple - 1.0) <= INIT_TOLERANCE)) return 0;
  }
  st->arg[0] = q0;
  st->arg[1] = signals;
  st->res[0] = st->phi;
  if (@NAME@_phi(st->arg, st->res, st->iw, st->w, 0)) return 0;
  for (i = 0; i < M_ALL; ++i) {
    const double a = fabs(st->phi[i]);
    if (!(a <= worst)) worst = a; /* a NaN is the worst */
  }
  return worst <= INIT_TOLERANCE;
}

int @NAME@_init(@NAME@_state* st, const double* q0, const double* signals) {
  casadi_int i;
  double at_rest[3 * NS], zero[N], z0[K1];
  if (!start_valid(st, q0, signals)) return INVALID_Q0;
  for (i = 0; i < 3 * NS; ++i) at_rest[i] = i < NS ? signals[i] : 0.0;
  for (i = 0; i < N; ++i) zero[i] = 0.0;
  for (i = 0; i < K1; ++i) z0[i] = 0.0;
  if (core(st, q0, zero, at_rest, z0) || !command_within(st->u_core)) return NO_STATIC_COMMAND;
  for (i = 0; i < N; ++i) st->q0[i] = q0[i];
  for (i = 0; i < L; ++i) st->u_static[i] = st->u_core[i];
  st->magic = MAGIC;
  return @NAME@_reset(st);
}

int @NAME@_reset(@NAME@_state* st) {
  casadi_int i, j;
  if (st->magic != MAGIC) return NOT_INITIALISED;
  for (i = 0; i < N; ++i) {
    st->q[i] = st->q0[i];
    st->qd[i] = st->qdd[i] = 0.0;
  }
  for (j = 0; j <= DELAY; ++j)
    for (i = 0; i < 3 * NS; ++i) st->sig[j][i] = 0.0;
  for (i = 0; i < K1; ++i) st->z[i] = st->sigma[i] = st->sigma_last[i] = 0.0;
  for (i = 0; i < L; ++i) st->u_safe[i] = st->u_core[i] = st->u_static[i];
#if ESTIMATOR
  @NAME@_estimator_start(&st->est, st->q0);
#endif
  st->k = 0;
  st->code = OK;
  st->t_last = 0.0;
  st->has_t_last = st->hold = 0;
  st->saturated = 0.0;
  return OK;
}

int @NAME@_reinit(@NAME@_state* st) {
  if (st->magic != MAGIC) return NOT_INITIALISED;
#if ESTIMATOR
  @NAME@_estimator_reinit(&st->est);
#endif
  return OK;
}

/* The step before its command's bookkeeping: the code; u_core holds the command when it is OK or COASTING. */
static int control(@NAME@_state* st, const double* y, double t, const double* signals) {
  casadi_int i;
  int status = 0;
  if (!isfinite(t)) return UNTRUSTED; /* the caller's time and path: a step that cannot trust them changes nothing */
  for (i = 0; i < 3 * NS; ++i)
    if (!isfinite(signals[i])) return UNTRUSTED;
#if ESTIMATOR
  {
    const casadi_int slot = (casadi_int)(st->k % (DELAY + 1));
    const double* msig;
    for (i = 0; i < 3 * NS; ++i) st->sig[slot][i] = signals[i];
    msig = st->k >= DELAY ? st->sig[(st->k - DELAY) % (DELAY + 1)] : st->sig[0];
    st->k += 1;
    status = @NAME@_estimator_update(&st->est, y, msig, signals);
    for (i = 0; i < N; ++i) {
      st->q[i] = st->est.q[i];
      st->qd[i] = st->est.qd[i];
    }
    if (status < 0) {
      @NAME@_estimator_applied(&st->est, 0);
      return UNTRUSTED;
    }
    if (status == 2) { /* lost: z held over the period that ends at the next step too */
      st->hold = 1;
      @NAME@_estimator_applied(&st->est, 0);
      return LOST;
    }
    if (!(st->est.violation <= PROJECTION_ACCEPT)) {
      @NAME@_estimator_applied(&st->est, 0);
      return UNTRUSTED;
    }
  }
#else
  st->k += 1;
  for (i = 0; i < N; ++i) {
    st->q[i] = y[i];
    st->qd[i] = y[N + i];
  }
#endif
  for (i = 0; i < N; ++i)
    if (!isfinite(st->q[i]) || !isfinite(st->qd[i])) {
#if ESTIMATOR
      @NAME@_estimator_applied(&st->est, 0);
#endif
      return UNTRUSTED;
    }
  if (status != 0) st->hold = 1; /* the estimate is a prediction: z not advanced over this period */
  if (st->has_t_last && t - st->t_last > MAX_GAP) st->hold = 1; /* a gap in the calls is not integrated over */
  if (KI != 0.0) { /* integral action (Controller._integrate): trapezoid, held after a saturated step */
    st->arg[0] = st->q;
    st->arg[1] = st->qd;
    st->arg[2] = signals;
    st->arg[3] = signals + NS;
    st->arg[4] = signals + 2 * NS;
    st->res[0] = st->sigma;
    if (@NAME@_sigma(st->arg, st->res, st->iw, st->w, 0)) return CORE_FAILED;
    if (st->has_t_last && t < st->t_last) { /* a time before the last one: a new run */
      for (i = 0; i < K1; ++i) st->z[i] = 0.0;
      st->has_t_last = 0;
      st->hold = 0;
    }
    if (st->has_t_last && t > st->t_last && !st->hold)
      for (i = 0; i < K1; ++i) st->z[i] += (0.5 * (t - st->t_last)) * (st->sigma_last[i] + st->sigma[i]);
    for (i = 0; i < K1; ++i) st->sigma_last[i] = st->sigma[i];
    st->t_last = t;
    st->has_t_last = 1;
  }
  if (core(st, st->q, st->qd, signals, st->z)) {
#if ESTIMATOR
    @NAME@_estimator_applied(&st->est, 0);
#endif
    return CORE_FAILED;
  }
  if (KI != 0.0) st->hold = st->saturated != 0.0; /* anti-windup: hold z over the next period */
  i = command_within(st->u_core);
#if ESTIMATOR
  @NAME@_estimator_applied(&st->est, i ? st->qdd : 0);
#endif
  if (!i) {
    for (i = 0; i < L; ++i)
      if (!isfinite(st->u_core[i])) return UNTRUSTED;
    return UNSAFE_COMMAND;
  }
  return status == 0 ? OK : COASTING;
}

int @NAME@_step(@NAME@_state* st, const double* y, double t, const double* signals, double* u) {
  casadi_int i;
  int code;
  if (st->magic != MAGIC) return NOT_INITIALISED;
  for (i = 0; i < K1; ++i) { /* the integral as it was: a step without a trustworthy command leaves it so */
    st->z_kept[i] = st->z[i];
    st->sigma_kept[i] = st->sigma_last[i];
  }
  st->t_kept = st->t_last;
  st->has_t_kept = st->has_t_last;
  code = control(st, y, t, signals);
  if (code == OK || code == COASTING) {
    for (i = 0; i < L; ++i) st->u_safe[i] = st->u_core[i];
  } else {
    for (i = 0; i < K1; ++i) {
      st->z[i] = st->z_kept[i];
      st->sigma_last[i] = st->sigma_kept[i];
    }
    st->t_last = st->t_kept;
    st->has_t_last = st->has_t_kept;
    st->hold = 1; /* nor over the period that ends at the next step */
  }
  for (i = 0; i < L; ++i) u[i] = st->u_safe[i];
  st->code = code;
  return code;
}
