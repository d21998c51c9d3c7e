#ifndef @GUARD@
#define @GUARD@

#include "@NAME@_functions.h"

#ifdef __cplusplus
extern "C" {
#endif

@MACROS@

@ESTIMATOR_STRUCT@
/* Everything the controller keeps between calls, and the work arrays of the generated functions: the caller's
 * memory (sizeof(@NAME@_state) = @STATE_BYTES@ bytes on x86-64 / LP64), one per controller, re-entrant per struct. */
typedef struct {
  unsigned long long magic;          /* @UNAME@_MAGIC once init succeeded (uninitialised memory is not a state) */
  long long k;                       /* steps since init or reset */
  int code;                          /* the last step's return code */
  int has_t_last, hold;              /* integral: t_last valid; hold: z not advanced over the next period */
  double t_last;                     /* the time of the last integration (s) */
  double saturated;                  /* the core step's saturation judgement (1: a limit kept u from the task) */
  double q0[@N@];                    /* init's q0 */
  double sig[@DELAY1@][@NS3@];       /* the signals passed in the last DELAY + 1 calls */
  double q[@N@], qd[@N@];            /* the estimate the last step used (without an estimator: y) */
  double z[@K1@], sigma[@K1@], sigma_last[@K1@]; /* integral action: z = int sigma dt, and sigma */
  double z_kept[@K1@], sigma_kept[@K1@], t_kept; /* the integral before the step: restored after a failed one */
  int has_t_kept;
  double qdd[@N@];                   /* the core step's commanded acceleration (1/s^2 times q's units) */
  double u_core[@L@];                /* the core step's command, before its checks */
  double u_safe[@L@];                /* the safe command: the last good one (after init: u_static) */
  double u_static[@L@];              /* the command that holds the crane at rest at q0 */
  double phi[@M_ALL@];               /* work: init's constraint check */
@ESTIMATOR_MEMBER@  const casadi_real* arg[@SZ_ARG@];
  casadi_real* res[@SZ_RES@];
  casadi_int iw[@SZ_IW@];
  casadi_real w[@SZ_W@];
} @NAME@_state;

/* q0 = the spec's static equilibrium at the start of its path (what acroboter's runs start from), the y index -> q
 * index map of the measurements, and the bounds every command u is within (the limits and the sanity bound):
 * constants for a caller without Python. */
extern const double @NAME@_q0[@N@];
extern const int @NAME@_y_coordinate[@NY@];
extern const double @NAME@_u_low[@L@], @NAME@_u_high[@L@];

int @NAME@_init(@NAME@_state* st, const double* q0, const double* signals);
int @NAME@_reset(@NAME@_state* st);
int @NAME@_reinit(@NAME@_state* st);
int @NAME@_step(@NAME@_state* st, const double* y, double t, const double* signals, double* u);
void @NAME@_path(double t, double* signals);

#ifdef __cplusplus
} /* extern "C" */
#endif

#endif /* @GUARD@ */
