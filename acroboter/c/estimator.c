/* The estimator of acroboter.sim.sensing.Estimator, statement for statement (docs/sensing.md): one text, rendered
 * into the stateful exported controller (static) and into the fast path's compiled estimator (extern).
 *
 * Needs, before it: <math.h>, the generated functions' header, the @NAME@_estimator struct, EST_API (static or
 * empty) and the numbers EST_N, EST_NS, EST_NY, EST_NU, EST_M, EST_NA, EST_ITERATIONS, EST_DELAY, EST_PREDICT,
 * EST_T, EST_ALPHA, EST_BETA, EST_TOLERANCE, EST_ACCEPT, EST_MAX_COAST and the arrays est_measured[EST_NY],
 * est_gate[EST_NY], est_unmeasured[EST_NU] (EST_NU > 0), est_axes[EST_NA][3] and est_axis_tol[EST_NA] (EST_NA > 0).
 * Fixed iteration counts, no heap, no globals but those constants. */

typedef int (*@NAME@_fn)(const casadi_real**, casadi_real**, casadi_int*, casadi_real*, int);

static int @NAME@_call2(@NAME@_estimator* e, @NAME@_fn f, const double* q, const double* sig, double* out) {
  e->arg[0] = q;
  e->arg[1] = sig;
  e->res[0] = out;
  return f(e->arg, e->res, e->iw, e->w, 0);
}

/* q onto phi(q, t) = 0 in place (Estimator.project): the unmeasured coordinates' least squares, then minimal-norm
 * Gauss-Newton steps, stopping at max |phi| <= EST_TOLERANCE; e->violation is max |phi| at the end. */
static int @NAME@_project(@NAME@_estimator* e, double* q, const double* sig) {
  int it, nan;
  casadi_int i;
  double v;
#if EST_NU > 0
  for (it = 0; it < EST_ITERATIONS; ++it) {
    if (@NAME@_call2(e, @NAME@_unmeasured_step, q, sig, e->dqu)) return 1;
    for (i = 0; i < EST_NU; ++i) q[est_unmeasured[i]] -= e->dqu[i];
  }
#endif
  for (it = 0; it <= EST_ITERATIONS; ++it) {
    if (@NAME@_call2(e, @NAME@_phi_rows, q, sig, e->phi)) return 1;
    v = 0.0;
    nan = 0;
    for (i = 0; i < EST_M; ++i) {
      double a = fabs(e->phi[i]);
      if (a != a) nan = 1;
      else if (a > v) v = a;
    }
    e->violation = nan ? NAN : v;
    if ((!nan && v <= EST_TOLERANCE) || it == EST_ITERATIONS) break;
    if (@NAME@_call2(e, @NAME@_projection_step, q, sig, e->dq)) return 1;
    for (i = 0; i < EST_N; ++i) q[i] -= e->dq[i];
  }
  return 0;
}

/* qd onto phi_q qd = -phi_t in place at q (Estimator._consistent_rates). */
static int @NAME@_rates(@NAME@_estimator* e, const double* q, double* qd, const double* sig) {
  casadi_int i;
  e->arg[0] = q;
  e->arg[1] = qd;
  e->arg[2] = sig;
  e->arg[3] = sig + EST_NS;
  e->res[0] = e->dq;
  if (@NAME@_rate_correction(e->arg, e->res, e->iw, e->w, 0)) return 1;
  for (i = 0; i < EST_N; ++i) qd[i] -= e->dq[i];
  return 0;
}

/* A new run from rest at q0 (Estimator.reset, its estimator part). */
EST_API void @NAME@_estimator_start(@NAME@_estimator* e, const double* q0) {
  casadi_int i, j;
  for (i = 0; i < EST_N; ++i) {
    e->qm[i] = e->q[i] = e->xf[i] = e->q_good[i] = e->pred[i] = q0[i];
    e->qdm[i] = e->qd[i] = e->vf[i] = e->dq[i] = 0.0;
  }
  for (j = 0; j <= EST_DELAY; ++j)
    for (i = 0; i < EST_N; ++i) e->acc[j][i] = 0.0;
  e->violation = e->jump = 0.0;
  e->k = 0;
  e->started = e->coasted = e->prev_valid = e->status = e->reason = e->distrust = 0;
  e->rejected = -1;
}

/* Restart the filter from the next sample (Estimator.reinit): its positions taken as they come (no gate), the
 * rates from zero; the estimate so far is the unmeasured coordinates' prior (the last accepted one if it is not
 * finite); the commanded accelerations are kept. */
EST_API void @NAME@_estimator_reinit(@NAME@_estimator* e) {
  casadi_int i;
  int finite = 1;
  for (i = 0; i < EST_N; ++i) if (!isfinite(e->qm[i])) finite = 0;
  for (i = 0; i < EST_N; ++i) {
    if (!finite) e->qm[i] = e->q_good[i];
    e->qdm[i] = e->vf[i] = 0.0;
    e->xf[i] = e->qm[i];
  }
  e->started = e->coasted = e->prev_valid = e->status = e->reason = e->distrust = 0;
  e->rejected = -1;
}

/* The acceleration commanded at this instant (Estimator.applied): the next predictions' (NULL or not finite: 0). */
EST_API void @NAME@_estimator_applied(@NAME@_estimator* e, const double* qdd) {
  casadi_int i;
  double* a = e->acc[(e->k - 1) % (EST_DELAY + 1)];
  int finite = qdd != 0;
  for (i = 0; finite && i < EST_N; ++i) if (!isfinite(qdd[i])) finite = 0;
  for (i = 0; i < EST_N; ++i) a[i] = finite ? qdd[i] : 0.0;
}

/* One update (Estimator.update): the sample y taken EST_DELAY periods ago, the path's signals at its time (sig_m)
 * and at t (sig_t). Returns e->status (0 accepted, 1 coasting, 2 lost), or -1 if a generated function failed. */
EST_API int @NAME@_estimator_update(@NAME@_estimator* e, const double* y, const double* sig_m, const double* sig_t) {
  casadi_int i, j;
  int reason = 0, rejected = -1, valid, lost, accepted, finite = 1;
  double worst = 0.0, scale;
  const casadi_int slot = (casadi_int)(e->k % (EST_DELAY + 1));
  const double* acc = e->acc[slot]; /* commanded at instant k - DELAY - 1: over the period that ends at y's time */
  double* q = e->qm;
  double* qd = e->qdm;
  (void)sig_t;
  e->k += 1;
  /* the prediction at the measurement's time: the unmeasured coordinates' prior, the measured ones' check */
  for (i = 0; i < EST_N; ++i) e->pred[i] = e->started ? q[i] + (EST_T * qd[i] + (0.5 * EST_T * EST_T) * acc[i]) : q[i];
  /* the sample's checks: finite, unit axes, a motion the crane can make (re-acquiring: two samples that agree) */
  for (j = 0; j < EST_NY; ++j)
    if (!isfinite(y[j])) {
      reason = 1;
      rejected = (int)j;
      break;
    }
#if EST_NA > 0
  for (j = 0; reason == 0 && j < EST_NA; ++j) {
    const double a = y[est_axes[j][0]], b = y[est_axes[j][1]], c = y[est_axes[j][2]];
    if (!(fabs(sqrt(a * a + b * b + c * c) - 1.0) <= est_axis_tol[j])) {
      reason = 2;
      rejected = (int)est_axes[j][0];
    }
  }
#endif
  valid = reason == 0;
  lost = e->coasted > EST_MAX_COAST || e->distrust > 4 * EST_MAX_COAST;
  e->jump = 0.0;
  if (valid && e->started && !lost) {
    scale = 1.0 + (double)e->coasted;
    for (j = 0; j < EST_NY; ++j) {
      const double r = fabs(y[j] - e->pred[est_measured[j]]) / (est_gate[j] * scale);
      if (r > worst) {
        worst = r;
        if (r > 1.0) rejected = (int)j;
      }
    }
    e->jump = worst;
    if (worst > 1.0) reason = 3;
  } else if (valid && lost) {
    for (j = 0; e->prev_valid && j < EST_NY; ++j) {
      const double r = fabs(y[j] - e->y_prev[j]) / est_gate[j];
      if (r > worst) {
        worst = r;
        if (r > 1.0) rejected = (int)j;
      }
    }
    e->jump = worst;
    if (!e->prev_valid || worst > 1.0) reason = 5;
  }
  if (valid)
    for (j = 0; j < EST_NY; ++j) e->y_prev[j] = y[j];
  e->prev_valid = valid;
  /* the measured coordinates overwritten by y unless it was rejected; onto phi(q, t) = 0 */
  for (i = 0; i < EST_N; ++i) q[i] = e->pred[i];
  if (reason == 0)
    for (j = 0; j < EST_NY; ++j) q[est_measured[j]] = y[j];
  if (@NAME@_project(e, q, sig_m)) return -1;
  if (reason == 0 && !(e->violation <= EST_ACCEPT)) {
    reason = 4;
    rejected = -1;
    for (i = 0; i < EST_N; ++i) q[i] = e->pred[i];
    if (@NAME@_project(e, q, sig_m)) return -1;
  }
  accepted = reason == 0;
  /* velocities: the alpha-beta filter of the projected positions (re-acquired: positions from the sample, the
   * coasted rates kept), then onto phi_q qd = -phi_t */
  if (!e->started) {
    for (i = 0; i < EST_N; ++i) {
      e->xf[i] = q[i];
      e->vf[i] = 0.0;
    }
    e->started = 1;
  } else if (accepted && lost) {
    for (i = 0; i < EST_N; ++i) e->xf[i] = q[i];
  } else { /* after coasting, the innovation built up over 1 + coasted periods: the rate's share scaled down */
    const double gain = EST_BETA / (EST_T * (1.0 + (double)e->coasted));
    for (i = 0; i < EST_N; ++i) {
      double r;
      e->xf[i] += EST_T * e->vf[i] + (0.5 * EST_T * EST_T) * acc[i];
      e->vf[i] += EST_T * acc[i];
      r = q[i] - e->xf[i];
      e->xf[i] += EST_ALPHA * r;
      e->vf[i] += gain * r;
    }
  }
  for (i = 0; i < EST_N; ++i) qd[i] = e->vf[i];
  if (@NAME@_rates(e, q, qd, sig_m)) return -1;
  for (i = 0; i < EST_N; ++i) {
    e->q[i] = q[i];
    e->qd[i] = qd[i];
  }
#if EST_DELAY > 0 && EST_PREDICT
  for (j = 1; j <= EST_DELAY; ++j) { /* carried forward over the delay: instants k - DELAY ... k - 1 */
    const double* a = e->acc[(slot + j) % (EST_DELAY + 1)];
    for (i = 0; i < EST_N; ++i) {
      e->q[i] += EST_T * e->qd[i] + (0.5 * EST_T * EST_T) * a[i];
      e->qd[i] += EST_T * a[i];
    }
  }
  if (@NAME@_project(e, e->q, sig_t)) return -1;
  if (@NAME@_rates(e, e->q, e->qd, sig_t)) return -1;
#endif
  e->coasted = accepted ? 0 : (e->coasted > EST_MAX_COAST ? EST_MAX_COAST + 1 : e->coasted + 1);
  if (accepted) e->distrust = lost ? 0 : (e->distrust > 0 ? e->distrust - 1 : 0); /* re-acquired: trusted anew */
  else if (e->distrust <= 4 * EST_MAX_COAST) e->distrust += 2;
  for (i = 0; i < EST_N; ++i)
    if (!isfinite(q[i]) || !isfinite(qd[i]) || !isfinite(e->xf[i]) || !isfinite(e->vf[i]) || !isfinite(e->q[i]) ||
        !isfinite(e->qd[i]))
      finite = 0;
  if (!finite) { /* back to the last accepted estimate, at rest, and lost: re-acquired from two agreeing samples */
    for (i = 0; i < EST_N; ++i) {
      q[i] = e->xf[i] = e->q[i] = e->q_good[i];
      qd[i] = e->vf[i] = e->qd[i] = 0.0;
    }
    e->violation = 0.0;
    e->coasted = EST_MAX_COAST + 1;
    reason = 6;
    rejected = -1;
    accepted = 0;
  } else if (accepted) {
    for (i = 0; i < EST_N; ++i) e->q_good[i] = q[i];
  }
  e->reason = reason;
  e->rejected = rejected;
  e->status = accepted ? 0 : (e->coasted > EST_MAX_COAST || e->distrust > 4 * EST_MAX_COAST ? 2 : 1);
  return e->status;
}
