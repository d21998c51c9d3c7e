"""The input limits in an exported step: acroboter.control.distribution's bounded distribution as CasADi graph pieces.

Bounds holds the spec's limits and preferred values (baked in as constants) and builds, for the graph of
one step (acroboter.codegen.step_graph.StepGraph), the limit checks, the clip, the three forms of the
distribution's step 2 (full rank, weighted, internal forces) and the box QP (CasADi's 'qrqp', generated
inline). The methods (acroboter.codegen.step_methods) decide which form a step uses.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.settings import SATURATION_TOLERANCE, SECONDARY_WEIGHT
from .solver_terms import cholesky_solve, mlm_bounded_terms

# --- Input limits: acroboter.control.distribution's bounded distribution, in the graph ----------------------------
#
# Every branch mirrors BoundedInputs (acroboter/distribution.py) step by step:
#   1. non-redundant inputs: the unbounded u (computed as before) if it is within the limits;
#   2. the unbounded minimiser of the distribution's objective (lexicographic or weighted), if within;
#   3. otherwise the strictly convex box QP with the Hessian of step 2.
# The later steps sit in CasADi Switch nodes (Function.if_else): the C evaluates only the branch taken,
# so a step whose limits are not reached costs a few comparisons more than an unbounded one.

QP_PLUGIN = "qrqp"  # CasADi's own active-set QP: generates plain C (its runtime is inlined), no heap
QP_OPTIONS = {
    "print_header": False, "print_iter": False, "print_info": False,
    # A failed QP: the C step returns nonzero (the generated code is the same either way); evaluating
    # StepExport.function from Python raises, as the controllers raise DistributionError.
    "error_on_fail": True,
    # The QP is divided by G's scale tr(G)/l (unit mean eigenvalue), so these are relative to the inputs' size.
    "constr_viol_tol": 1e-12, "dual_inf_tol": 1e-12,
}


def symmetric(matrix: ca.SX) -> ca.SX:
    return 0.5 * (matrix + matrix.T)


def scale_and_weight(hessian: ca.SX, weight: float) -> tuple[ca.SX, ca.SX]:
    """(scale, μ) = (tr(G)/l, weight·tr(G)/l), or (1, 1) if tr(G) <= 0 (G = 0), as BoundedInputs; NaN stays NaN."""
    mean = ca.trace(hessian) / hessian.shape[0]
    positive, zero = mean > 0, mean <= 0
    return (ca.if_else(positive, mean, ca.if_else(zero, 1.0, np.nan)),
            ca.if_else(positive, weight * mean, ca.if_else(zero, 1.0, np.nan)))



class Bounds:
    """The bounded distribution's pieces of one step's graph (limits and preferred values baked in)."""

    def __init__(self, graph):  # an acroboter.codegen.step_graph.StepGraph
        self.graph = graph
        self.lower, self.upper, self.preferred = graph.export.spec.input_limits()
        self.l = graph.l
        self.bounded = bool(np.isfinite(self.lower).any() or np.isfinite(self.upper).any())
        self._count = 0
        self._qp_solver = None
        self.used_qp = False
        # The stateful export with integral action (acroboter.codegen.controller_c): every bounded branch returns
        # [u; QP ran (0/1); step 2's minimiser] (what BoundedInputs records as bounded_step and unbounded), for
        # the anti-windup's saturation judgement (saturation below).
        self.report = False
        # The parametric step (acroboter.codegen.fast_step): the preferred values as a run-time MX input (None: baked).
        self.preferred_input: ca.MX | None = None

    def name(self, what: str) -> str:
        self._count += 1
        return f"{self.graph.export.name}_{what}_{self._count}"

    def sx_call(self, what: str, sx_inputs: list[ca.SX], sx_outputs: list[ca.SX], args: list[ca.MX]) -> list[ca.MX]:
        fn = ca.Function(self.name(what), sx_inputs, [ca.densify(o) for o in sx_outputs], {"cse": True})
        out = fn(*[ca.densify(a) for a in args])
        return list(out) if isinstance(out, tuple) else [out]

    def switch(self, what: str, condition: ca.MX, args: list[ca.MX], when_true, when_false) -> ca.MX:
        """when_true(args) if condition else when_false(args), only the selected branch evaluated."""
        symbols = [ca.MX.sym(f"a{i}", a.sparsity()) for i, a in enumerate(args)]
        name = self.name(what)
        f_true = ca.Function(f"{name}_true", symbols, [ca.densify(when_true(symbols))])
        f_false = ca.Function(f"{name}_false", symbols, [ca.densify(when_false(symbols))])
        return ca.Function.if_else(name, f_true, f_false)(condition, *args)

    # -- elementwise limits --

    def within(self, u):
        """1 if every finite limit holds (NaN fails, as in BoundedInputs.within_limits), else 0."""
        x = ca.SX.sym("u", self.l)
        checks = [x[i] >= self.lower[i] for i in range(self.l) if np.isfinite(self.lower[i])]
        checks += [x[i] <= self.upper[i] for i in range(self.l) if np.isfinite(self.upper[i])]
        cond = checks[0]
        for check in checks[1:]:
            cond = ca.logic_and(cond, check)
        return self.sx_call("within", [x], [cond], [u])[0]

    def runtime_within(self, u, limits: ca.MX):
        """The parametric step's step-1 check, limits = [lower; upper; preferred] a run-time input: 1 if
        lower <= u <= upper entry by entry (±inf for no limit), 0 otherwise and for a NaN (the caller then takes
        the reference path)."""
        l = self.l
        x, lim = ca.SX.sym("u", l), ca.SX.sym("limits", 3 * l)
        cond = ca.SX(1)
        for i in range(l):
            cond = ca.logic_and(cond, ca.logic_and(x[i] >= lim[i], x[i] <= lim[l + i]))
        return self.sx_call("within", [x, lim], [cond], [u, limits])[0]

    def clip(self, u):
        x = ca.SX.sym("u", self.l)
        entries = []
        for i in range(self.l):
            e = x[i]
            if np.isfinite(self.lower[i]):
                e = ca.fmax(e, self.lower[i])
            if np.isfinite(self.upper[i]):
                e = ca.fmin(e, self.upper[i])
            entries.append(e)
        return self.sx_call("clip", [x], [ca.vertcat(*entries)], [u])[0]

    # -- the QP --

    def qp(self, hessian: ca.MX, gradient: ca.MX, start: ca.MX) -> ca.MX:
        """min ½xᵀHx + gᵀx, lower <= x <= upper (CasADi's qrqp), clipped onto the limits as Python does.

        Started at `start` (step 2's u2) clipped, with the bounds it violates as the initial active set
        (multiplier guesses ±1): the minimiser is unique, the start only saves iterations."""
        if self._qp_solver is None:
            l = self.l
            self._qp_solver = ca.conic(f"{self.graph.export.name}_qp", QP_PLUGIN,
                                       {"h": ca.Sparsity.dense(l, l), "a": ca.Sparsity(0, l)}, QP_OPTIONS)
        self.used_qp = True
        x = ca.SX.sym("u", self.l)
        signs = []
        for i in range(self.l):
            sign = ca.SX(0)
            if np.isfinite(self.lower[i]):
                sign = ca.if_else(x[i] < self.lower[i], -1.0, sign)
            if np.isfinite(self.upper[i]):
                sign = ca.if_else(x[i] > self.upper[i], 1.0, sign)
            signs.append(sign)
        (lam0,) = self.sx_call("active_guess", [x], [ca.vertcat(*signs)], [start])
        result = self._qp_solver(h=hessian, g=gradient, lbx=ca.DM(self.lower), ubx=ca.DM(self.upper),
                                 x0=self.clip(start), lam_x0=lam0)["x"]
        return self.clip(result)

    def finish(self, u2: ca.MX, qp_args: list[ca.MX], qp_terms, report: bool | None = None) -> ca.MX:
        """Step 2's u2 if within the limits, else the QP; qp_terms(qp_args) -> (H, g), in the QP branch.
        report (default self.report): [u; QP ran; u2] instead of u."""
        if not self.bounded:
            return u2
        if self.report if report is None else report:
            return self.switch("bounded", self.within(u2), [u2, *qp_args], lambda a: ca.vertcat(a[0], 0, a[0]),
                               lambda a: ca.vertcat(self.qp(*qp_terms(a[1:]), a[0]), 1, a[0]))
        return self.switch("bounded", self.within(u2), [u2, *qp_args], lambda a: a[0],
                           lambda a: self.qp(*qp_terms(a[1:]), a[0]))

    def report_clip(self, u: ca.MX) -> ca.MX:
        """eq15/kappa's clip with the report: Python's distribution of G = I has u2 = the recovery's u."""
        if not self.report:
            return self.clip(u)
        return ca.vertcat(self.clip(u), 1 - self.within(u), u)

    def saturation(self, ran: ca.MX, u2: ca.MX) -> ca.MX:
        """controllers.Controller.saturation in the graph, evaluated only where the QP ran (a Switch): the servo
        accelerations a = E u2 of step 2's minimiser (E = sigma_q P H, codegen.solver_terms.mlm_bounded_terms) asked
        of the limits in the bounded least squares min |E u - a|^2 (BoundedInputs, lexicographic); saturated (1)
        if its input misses a by more than SATURATION_TOLERANCE * max(1, max |a|)."""
        graph = self.graph
        l, k = self.l, graph.k
        e_sx = mlm_bounded_terms(graph.model, graph.params)["servo_map"]
        n_in = len(graph.inputs)

        def judged(a):
            (e_map,) = self.sx_call("judge_map", graph.sx_inputs, [e_sx], a[1 : 1 + n_in])
            asked = ca.mtimes(e_map, a[0])
            if l > k:
                best = self.internal(e_map, asked, report=False)
            else:
                best = self.full_rank(ca.mtimes(e_map.T, e_map), -ca.mtimes(e_map.T, asked), report=False)
            miss = ca.mmax(ca.fabs(ca.mtimes(e_map, best) - asked))
            return miss > SATURATION_TOLERANCE * ca.fmax(1.0, ca.mmax(ca.fabs(asked)))

        return self.switch("saturation", ran, [u2, *graph.inputs], judged, lambda a: ca.MX(0.0))

    # -- the three forms of step 2 --

    def full_rank(self, hessian: ca.MX, gradient: ca.MX, report: bool | None = None) -> ca.MX:
        """Lexicographic, G nonsingular (no internal forces): u2 = −G⁻¹g, QP Hessian G (divided by tr(G)/l)."""
        l = self.l
        g, f = ca.SX.sym("G", l, l), ca.SX.sym("g", l)
        u2 = self.sx_call("unbounded", [g, f], [-cholesky_solve(symmetric(g), f)], [hessian, gradient])[0]

        def terms(a):
            scale, _ = scale_and_weight(g, 0.0)
            return self.sx_call("qp_terms", [g, f], [symmetric(g) / scale, f / scale], a)

        return self.finish(u2, [hessian, gradient], terms, report)

    def weighted(self, hessian: ca.MX, gradient: ca.MX, weight: float) -> ca.MX:
        """(G + μI) u2 = −g + μ u_pref by Cholesky, μ = weight · tr(G)/l (1 if G = 0); the QP has the same
        Hessian."""
        l = self.l
        g, f = ca.SX.sym("G", l, l), ca.SX.sym("g", l)
        scale, mu = scale_and_weight(g, weight)
        hess = symmetric(g) + mu * ca.SX.eye(l)
        grad = f - mu * ca.DM(self.preferred)
        u2, hq, gq = self.sx_call("weighted", [g, f], [-cholesky_solve(hess, grad), hess / scale, grad / scale],
                                  [hessian, gradient])
        return self.finish(u2, [hq, gq], lambda a: a)

    def internal(self, servo_map: ca.MX, target: ca.MX, report: bool | None = None) -> ca.MX:
        """Lexicographic with internal forces (MLM, more inputs than servo-constraints), E full row rank.

        Python's eigen split of G = EᵀE keeps the range of Eᵀ and sets the null space Z to u_pref:
        u2 = E⁺e + ZZᵀu_pref = u_pref + Eᵀ(EEᵀ)⁻¹(e − E u_pref), ZZᵀ = I − Eᵀ(EEᵀ)⁻¹E. QP Hessian
        G + μZZᵀ, gradient −Eᵀe − μZZᵀu_pref, μ = SECONDARY_WEIGHT · tr(G)/l (tr(G) = |E|_F²).
        """
        l, k = self.l, self.graph.k
        e_map, e = ca.SX.sym("E", k, l), ca.SX.sym("e", k)
        gram = ca.mtimes(e_map, e_map.T)
        if self.preferred_input is not None:  # the parametric step: u_pref a run-time input (no QP follows)
            pref = ca.SX.sym("preferred", l)
            u2 = pref + ca.mtimes(e_map.T, cholesky_solve(gram, e - ca.mtimes(e_map, pref)))
            return self.sx_call("internal", [e_map, e, pref], [u2], [servo_map, target, self.preferred_input])[0]
        pref = ca.DM(self.preferred)
        u2 = pref + ca.mtimes(e_map.T, cholesky_solve(gram, e - ca.mtimes(e_map, pref)))
        u2 = self.sx_call("internal", [e_map, e], [u2], [servo_map, target])[0]

        def terms(a):
            hess = symmetric(ca.mtimes(e_map.T, e_map))
            projector = symmetric(ca.SX.eye(l) - ca.mtimes(e_map.T, cholesky_solve(gram, e_map)))
            scale, mu = scale_and_weight(hess, SECONDARY_WEIGHT)
            gradient = -ca.mtimes(e_map.T, e) - mu * ca.mtimes(projector, pref)
            return self.sx_call("internal_qp", [e_map, e], [(hess + mu * projector) / scale, gradient / scale], a)

        return self.finish(u2, [servo_map, target], terms, report)

    def task(self, hessian: ca.MX, gradient: ca.MX, servo_map: ca.MX) -> ca.MX:
        """The fit ½uᵀGu + gᵀu with redundant inputs, lexicographic in the servo accelerations E u, as
        BoundedInputs.solve_task: e_F = E u_F, u_F = −Eᵀ(E G Eᵀ)⁻¹E g (SX Cholesky), then internal(E, e_F)."""
        l, k = self.l, self.graph.k
        g, f, e_map = ca.SX.sym("G", l, l), ca.SX.sym("g", l), ca.SX.sym("E", k, l)
        reduced = symmetric(ca.mtimes([e_map, g, e_map.T]))
        w = cholesky_solve(reduced, ca.mtimes(e_map, f))
        (target,) = self.sx_call("task_target", [g, f, e_map], [-ca.mtimes(e_map, ca.mtimes(e_map.T, w))],
                                 [hessian, gradient, servo_map])
        return self.internal(servo_map, target)

    def after_unbounded(self, u0: ca.MX, extra: list[ca.MX], branch) -> ca.MX:
        """Python's step 1: the unbounded u0 if within the limits, else branch(step inputs, extra)."""
        if not self.bounded:
            return u0
        inputs = self.graph.inputs
        n_in = len(inputs)
        report = self.report
        return self.switch("limits", self.within(u0), [u0, *inputs, *extra],
                           lambda a: ca.vertcat(a[0], 0, a[0]) if report else a[0],
                           lambda a: branch(a[1 : 1 + n_in], a[1 + n_in :]))


def symmetric_numeric(matrix: np.ndarray) -> np.ndarray:
    return 0.5 * (matrix + matrix.T)

