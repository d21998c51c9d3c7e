"""The estimator of acroboter.sim.sensing as one compiled function, for the Python loop's fast path (issue 23 item 2).

    int <name>_estimate(double* state, casadi_int* iw, double* w, const casadi_real** arg, casadi_real** res,
                        const double* y, const double* sig_m, const double* sig_t, long long slot, int started)

is Estimator.estimate after the sensor: from the measurement y (taken delay periods ago, noise and quantisation
the Python sensor's), the path's signals at the measurement's time (sig_m) and at t (sig_t), it predicts the
unmeasured coordinates with the commanded acceleration, projects onto φ(q, t) = 0 (Gauss–Newton: the unmeasured
coordinates' least squares, then minimal-norm steps, stopping at max |φ| <= PROJECTION_TOLERANCE), runs the α-β
filter, corrects the rates onto φ_q q̇ = −φ_t and, with a delay and predict_delay, carries the estimate forward to t
and projects it again: statement for statement the Python (and the stateful exported controller's estimator,
acroboter.codegen.controller_c, whose SX functions it shares: max-free φ rows, the Gauss–Newton steps by SX Cholesky).

`state` is one block the caller owns: [qm, qdm, xf, vf, q, qd (n each), acc ((delay + 1) n: the commanded
accelerations, the caller's ring), dq (n), dqu (max(nu, 1)), phi (m), violation (1)]. Returns 0, or 1 if a generated
function failed. Fixed iteration counts; no heap.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from ..model.fingerprint import codegen_hash
from ..model.schema import Sensing
from ..model.sensing_layout import PROJECTION_TOLERANCE, measured_indices
from ..model.spec import Spec
from .structured import cholesky_solve, independent_rows
from .symbolic import build_symbolic_model

__all__ = ["EstimatorExport", "build_estimator", "estimator_key", "state_layout", "write_estimator"]


@dataclass
class EstimatorExport:
    name: str
    n: int
    n_signals: int
    measured: np.ndarray
    unmeasured: np.ndarray
    rows: list[int]
    period: float
    alpha: float
    beta: float
    delay: int
    iterations: int
    predict: bool
    functions: list[ca.Function]
    work: tuple[int, int, int, int]


def state_layout(n: int, delay: int, nu: int, m: int) -> dict[str, tuple[int, int]]:
    """(offset, size) of each part of the state block."""
    parts = [("qm", n), ("qdm", n), ("xf", n), ("vf", n), ("q", n), ("qd", n), ("acc", (delay + 1) * n), ("dq", n),
             ("dqu", max(nu, 1)), ("phi", max(m, 1)), ("violation", 1)]
    out, offset = {}, 0
    for name, size in parts:
        out[name] = (offset, size)
        offset += size
    out["size"] = (offset, 0)
    return out


def estimator_key(spec: Spec, sensing: Sensing) -> str:
    h = hashlib.sha256(f"estimator 1\n{spec.model_hash()}\n{codegen_hash()}\n{sensing.model_dump_json()}\n"
                       f"{spec.controller.rate_hz!r}\n".encode())
    h.update((Path(__file__).resolve()).read_bytes())
    return h.hexdigest()


def build_estimator(spec: Spec, sensing: Sensing, name: str) -> EstimatorExport:
    model = build_symbolic_model(spec)
    lay = model.layout
    index, _, _ = measured_indices(spec, lay, sensing)
    unmeasured = np.setdiff1d(np.arange(lay.n), index)
    rows = independent_rows(model)
    period = 1.0 / spec.controller.rate_hz
    pole = math.exp(-period / sensing.velocity_filter_s)
    q, qd, s, sd, _ = model.inputs
    phi = ca.SX(model.phi)[rows, 0]
    a = ca.SX(model.phi_q)[rows, :]
    gram = ca.mtimes(a, a.T)

    def min_norm(b):  # aᵀ(a aᵀ)⁻¹ b, as Estimator._min_norm
        return ca.densify(ca.mtimes(a.T, cholesky_solve(gram, b)))

    functions = [
        ca.Function(f"{name}_phi_rows", [q, s], [ca.densify(phi)], ["q", "s"], ["phi"], {"cse": True}),
        ca.Function(f"{name}_projection_step", [q, s], [min_norm(phi)], ["q", "s"], ["dq"], {"cse": True}),
        ca.Function(f"{name}_rate_correction", [q, qd, s, sd], [min_norm(ca.SX(model.phi_dot)[rows, 0])],
                    ["q", "qd", "s", "sd"], ["dqd"], {"cse": True}),
    ]
    if unmeasured.size:
        au = a[:, unmeasured.tolist()]
        step_u = cholesky_solve(ca.mtimes(au.T, au), ca.mtimes(au.T, phi))  # as Estimator._least_squares
        functions.append(ca.Function(f"{name}_unmeasured_step", [q, s], [ca.densify(step_u)], ["q", "s"],
                                     ["dq_unmeasured"], {"cse": True}))
    work = tuple(max(getattr(f, attr)() for f in functions) for attr in ("sz_arg", "sz_res", "sz_iw", "sz_w"))
    return EstimatorExport(name, lay.n, lay.n_signals, index, unmeasured, rows, period, 1.0 - pole * pole,
                           (1.0 - pole) ** 2, sensing.delay_periods, sensing.projection_iterations,
                           bool(sensing.predict_delay), functions, work)  # type: ignore[arg-type]


def _source(e: EstimatorExport) -> str:
    lay = state_layout(e.n, e.delay, e.unmeasured.size, len(e.rows))
    off = {k: v[0] for k, v in lay.items()}
    measured = ", ".join(str(int(i)) for i in e.measured) or "0"
    unmeasured = ", ".join(str(int(i)) for i in e.unmeasured) or "0"
    has_u = e.unmeasured.size > 0
    name = e.name
    unmeasured_loop = f"""  for (it = 0; it < ITERATIONS; ++it) {{
    if (call2(arg, res, iw, w, {name}_unmeasured_step, q, sig, dqu)) return 1;
    for (i = 0; i < NU; ++i) q[unmeasured[i]] -= dqu[i];
  }}
""" if has_u else ""
    return f"""/* {name}: the Python loop's estimator (acroboter.codegen.estimator_c). Generated: do not edit. */
#include <math.h>
#include "{name}_functions.h"

#define N {e.n}
#define NS {e.n_signals}
#define NY {e.measured.size}
#define NU {e.unmeasured.size}
#define M {len(e.rows)}
#define ITERATIONS {e.iterations}
#define DELAY {e.delay}
#define PREDICT {1 if e.predict else 0}
#define T {e.period!r}
#define ALPHA {e.alpha!r}
#define BETA {e.beta!r}
#define TOLERANCE {PROJECTION_TOLERANCE!r}

static const casadi_int measured[{max(e.measured.size, 1)}] = {{{measured}}};
{f"static const casadi_int unmeasured[{e.unmeasured.size}] = {{{unmeasured}}};" if has_u else ""}

typedef int (*fn2)(const casadi_real**, casadi_real**, casadi_int*, casadi_real*, int);

static int call2(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, fn2 f,
                 const double* q, const double* sig, double* out) {{
  arg[0] = q; arg[1] = sig;
  res[0] = out;
  return f(arg, res, iw, w, 0);
}}

/* q onto phi(q, t) = 0 in place (Estimator.project) */
static int project(double* s, const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, double* q,
                   const double* sig) {{
  int it, nan;
  casadi_int i;
  double v;
  double* dq = s + {off['dq']};
  double* dqu = s + {off['dqu']};
  double* phi = s + {off['phi']};
  (void)dqu;
{unmeasured_loop}  for (it = 0; it <= ITERATIONS; ++it) {{
    if (call2(arg, res, iw, w, {name}_phi_rows, q, sig, phi)) return 1;
    v = 0.0;
    nan = 0;
    for (i = 0; i < M; ++i) {{
      double a = fabs(phi[i]);
      if (a != a) nan = 1;
      else if (a > v) v = a;
    }}
    s[{off['violation']}] = nan ? NAN : v;
    if ((!nan && v <= TOLERANCE) || it == ITERATIONS) break;
    if (call2(arg, res, iw, w, {name}_projection_step, q, sig, dq)) return 1;
    for (i = 0; i < N; ++i) q[i] -= dq[i];
  }}
  return 0;
}}

/* qd onto phi_q qd = -phi_t in place at q (Estimator._consistent_rates) */
static int rates(double* s, const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
                 const double* q, double* qd, const double* sig) {{
  casadi_int i;
  double* dq = s + {off['dq']};
  arg[0] = q; arg[1] = qd; arg[2] = sig; arg[3] = sig + NS;
  res[0] = dq;
  if ({name}_rate_correction(arg, res, iw, w, 0)) return 1;
  for (i = 0; i < N; ++i) qd[i] -= dq[i];
  return 0;
}}

int {name}_estimate(double* s, casadi_int* iw, double* w, const casadi_real** arg, casadi_real** res,
                    const double* y, const double* sig_m, const double* sig_t, long long slot, int started) {{
  casadi_int i, j;
  double *qm = s + {off['qm']}, *qdm = s + {off['qdm']}, *xf = s + {off['xf']}, *vf = s + {off['vf']};
  double *q = s + {off['q']}, *qd = s + {off['qd']}, *ring = s + {off['acc']};
  const double* acc = ring + slot * N;  /* commanded at instant k - DELAY - 1 */
  (void)sig_t; (void)j;
  if (started) for (i = 0; i < N; ++i) qm[i] += T * qdm[i] + (0.5 * T * T) * acc[i];
  for (j = 0; j < NY; ++j) qm[measured[j]] = y[j];
  if (project(s, arg, res, iw, w, qm, sig_m)) return 1;
  if (!started) {{
    for (i = 0; i < N; ++i) {{ xf[i] = qm[i]; vf[i] = 0.0; }}
  }} else {{
    for (i = 0; i < N; ++i) {{
      double r;
      xf[i] += T * vf[i] + (0.5 * T * T) * acc[i];
      vf[i] += T * acc[i];
      r = qm[i] - xf[i];
      xf[i] += ALPHA * r;
      vf[i] += (BETA / T) * r;
    }}
  }}
  for (i = 0; i < N; ++i) qdm[i] = vf[i];
  if (rates(s, arg, res, iw, w, qm, qdm, sig_m)) return 1;
  for (i = 0; i < N; ++i) {{ q[i] = qm[i]; qd[i] = qdm[i]; }}
#if DELAY > 0 && PREDICT
  for (j = 1; j <= DELAY; ++j) {{  /* carried forward over the delay: instants k - DELAY ... k - 1 */
    const double* a = ring + ((slot + j) % (DELAY + 1)) * N;
    for (i = 0; i < N; ++i) {{
      q[i] += T * qd[i] + (0.5 * T * T) * a[i];
      qd[i] += T * a[i];
    }}
  }}
  if (project(s, arg, res, iw, w, q, sig_t)) return 1;
  if (rates(s, arg, res, iw, w, q, qd, sig_t)) return 1;
#endif
  return 0;
}}
"""


def write_estimator(e: EstimatorExport, folder: Path) -> None:
    """<name>_functions.c/.h (CasADi) and <name>.c (the loop) into `folder`: deterministic bytes."""
    folder.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{e.name}_functions.c", {"with_header": True})
    for function in e.functions:
        cg.add(function)
    cg.generate(str(folder) + "/")
    (folder / f"{e.name}.c").write_text(_source(e))
