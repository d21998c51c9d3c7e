/* The estimator's state (acroboter.sim.sensing.Estimator; docs/sensing.md): what it keeps between calls, and the
 * work arrays of its generated functions. Sizes fixed at generation. */
typedef struct {
  double qm[@N@], qdm[@N@];         /* the estimate at the measurement's time: positions (projected) and rates */
  double xf[@N@], vf[@N@];          /* the alpha-beta filter: position and velocity */
  double q[@N@], qd[@N@];           /* the estimate at t, handed to the control step */
  double acc[@DELAY1@][@N@];        /* accelerations commanded at the last DELAY + 1 instants (a ring) */
  double pred[@N@];                 /* this update's prediction at the measurement's time */
  double q_good[@N@];               /* qm after the last accepted sample */
  double y_prev[@NY1@];             /* the last sample that was finite with unit axes (re-acquisition) */
  double dq[@N@], dqu[@NU1@], phi[@M1@];  /* work: a projection or rate step; phi over the independent rows */
  double violation;                 /* max |phi| after the last projection (converged: <= PROJECTION_ACCEPT) */
  double jump;                      /* the last sample's largest |y[j] - its prediction| / its gate */
  long long k;                      /* updates since init, reset or reinit */
  int started;                      /* the filter has its first sample */
  int coasted;                      /* samples rejected in a row (capped at MAX_COAST + 1) */
  int prev_valid;                   /* y_prev holds a sample */
  int status;                       /* the last update: 0 accepted, 1 coasting on the prediction, 2 lost */
  int reason;                       /* why the last sample was rejected: 0 it was not, 1 not finite, 2 a unit axis
                                       off unit length, 3 further from its prediction than its gate, 4 the
                                       projection did not converge, 5 not confirmed by the sample before it
                                       (re-acquisition), 6 the estimate turned non-finite (reset to the last
                                       accepted one, at rest) */
  int rejected;                     /* the y index that failed the check (-1: none, or not one coordinate's) */
  int distrust;                     /* +2 per rejected sample, -1 per accepted one: a fault that keeps coming back
                                       (more than a third of the samples) loses the estimate past 4 MAX_COAST */
  const casadi_real* arg[@SZ_ARG@];
  casadi_real* res[@SZ_RES@];
  casadi_int iw[@SZ_IW@];
  casadi_real w[@SZ_W@];
} @NAME@_estimator;
