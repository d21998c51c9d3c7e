"""The three inverse-dynamics controllers of the paper (docs/model.md §6), fed only by the compiled model.

Every controller maps (q, q̇, t) to the input u. One call into the compiled library gives what
the method needs at the state (acroboter.codegen.solver_terms); the remaining linear algebra is LAPACK through
scipy on preallocated arrays.

  ρ   = γ   + 2Ωμ φ̇ + Ω² φ               (geometric constraints, penalty dynamics)
  ρ_s = γ_s + 2k_D σ̇ + k_P² σ + k_I z    (servo-constraints: the tracking error dynamics)

z = ∫σ dt is the integral action's state (docs/integral_action.md), held here, in the base class,
for every method: trapezoidal over each control period from σ at the period's two ends, frozen over
a period whose input was saturated (conditional integration: the anti-windup), and written into the
generated functions' parameter vector, so that every method, recovery and bounded distribution
reads the same ρ_s. With k_I = 0 (the default) nothing of it runs and z stays 0.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from ..model.controller_parameters import integral_slice
from ..model.settings import MLM_RCOND_LIMIT, PENALTY_SECONDARY_WEIGHT, SATURATION_TOLERANCE, Gains
from ..model.spec import Spec
from ..model.spec_checks import task_components
from .distribution import BoundedInputs, DistributionError
from .path import DesiredPath
from .recovery import InputRecovery
from .underactuation import Underactuation


class SingularSystemError(RuntimeError):
    """The controller's linear system has no unique solution (e.g. redundant constraints)."""


def unbounded(spec: Spec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Limits that bound nothing (for the ideal inverse dynamics), with the spec's preferred values."""
    _, _, preferred = spec.input_limits()
    return np.full(preferred.size, -np.inf), np.full(preferred.size, np.inf), preferred


class Controller:
    """Shared part: load state, signals and parameters into the model's input buffers.

    Every controller honours the spec's input limits (acroboter.control.distribution): an unbounded
    solution within them is used as it is; otherwise, or where there are more inputs than
    servo-constraints (redundant actuation), a small bounded QP gives the input.
    """

    name = "controller"
    terms_function = ""
    bounded_function = ""
    secondary_weight = 0.0  # acroboter.control.distribution: 0 lexicographic, > 0 weighted
    fast_refusal: str | None = None  # make_controller(fast=True) fell back to this reference: why

    def __init__(self, model, path: DesiredPath, gains: Gains, limits=None):
        """`model`: a CompiledModel, or any backend with the same buffers and functions.

        `limits`: (min, max, preferred) per input; default the spec's (Spec.input_limits).
        """
        self.model, self.path, self.gains = model, path, gains
        lay = model.layout
        self.n, self.m, self.k, self.l = lay.n, lay.m, lay.k, lay.l
        self._params = gains.parameter_vector(self.k)
        self._fn = model.functions[self.terms_function]
        self.terms = self._fn.outputs  # refreshed by every _load
        self._bounded_fn = model.functions[self.bounded_function]
        self.bounded_terms = self._bounded_fn.outputs
        self._q, self._qd, self._p, self._signals = model.q, model.qd, model.p, model.signals
        self.lam = np.zeros(self.m)
        self.lam_hat = np.zeros(self.k)
        self.u = np.zeros(self.l)
        self.limits = BoundedInputs(*(model.spec.input_limits() if limits is None else limits),
                                    weight=self.secondary_weight if self.l > self.k else 0.0)
        # Per input after each compute(): -1 held at its lower limit, +1 at its upper limit, 0 free.
        self.limit_state = self.limits.limit_state
        self._servo_fn = model.functions["mlm_bounded_terms"]  # E = σ_q P H, to judge saturation
        self._judge = BoundedInputs(self.limits.lower, self.limits.upper, self.limits.preferred)
        # More inputs than servo-constraints: the task leaves internal forces free, always distribute.
        self.redundant_inputs = self.l > self.k
        # Integral action: z = ∫σ dt per servo-constraint, in p after the scalar gains.
        self.ki = float(gains.ki)
        self.anti_windup = True  # conditional integration: z holds over a period whose input saturated
        self.integral = np.zeros(self.k)  # z
        self._z = self._p[integral_slice(self.k)]  # z's place in the parameter buffer
        self._sigma_fn = model.functions["sigma"]
        self._sigma_last = np.zeros(self.k)
        self._t_last: float | None = None
        self._hold = False  # the last step saturated: do not integrate over the period after it
        self._saturated: bool | None = None  # saturation() of the last compute(), once judged
        # How a limit is met (docs/saturation.md): None, the bounded least squares ("qp"); else the saturated
        # inputs held at their limits and the task reduced by the spec's priority (acroboter.control.underactuation).
        self.underactuation: Underactuation | None = None
        if gains.saturation == "underactuation":
            self.underactuation = Underactuation(self.limits.lower, self.limits.upper, self.limits.preferred,
                                                 task_components(model.spec), gains.priority, gains.dwell,
                                                 gains.release_margin)
        elif gains.saturation != "qp":
            raise ValueError(f"saturation: expected 'qp' or 'underactuation', found {gains.saturation!r}")
        self._t_now = 0.0
        # False when a wrapper advances z itself before _compute (acroboter.control.fast_path.FastController)
        self._integrate_in_load = True

    def reset(self) -> None:
        """Forget the integral action's state (z = 0) and the held inputs: for a new run with the same controller."""
        self.integral[:] = 0.0
        self._t_last, self._hold = None, False
        if self.underactuation is not None:
            self.underactuation.reset()

    def hold_integral(self) -> None:
        """Do not integrate z over the period that ends at the next compute(): the estimate it reads is a
        prediction, not a measurement (acroboter.sim.stateful_controller; the exported controller does the same)."""
        self._hold = True

    def _integrate(self, t: float) -> None:
        """z += ½ (t − t_prev)(σ_prev + σ) with σ at the state in the buffers, unless the last step
        saturated (anti-windup); then z into p. A time before the last one starts a new run (z = 0)."""
        self._sigma_fn.call()  # σ at the state and signals just loaded
        sigma = self._sigma_fn.outputs["sigma"]
        if self._t_last is not None and t < self._t_last:
            self.reset()
        if self._t_last is not None and t > self._t_last and not self._hold:
            self.integral += (0.5 * (t - self._t_last)) * (self._sigma_last + sigma)
        self._sigma_last[:] = sigma
        self._t_last = t
        self._z[:] = self.integral

    def compute(self, q: np.ndarray, qd: np.ndarray, t: float, signals=None) -> np.ndarray:
        """The input u at state (q, q̇) and time t (a view of an internal buffer).

        `signals`: the path's [s, ṡ, s̈] at t if already known (e.g. from DesiredPath.table);
        otherwise they are evaluated here. With integral action, z is advanced to t first, and the
        step's saturation is judged after it (for the anti-windup of the next period).
        """
        self._saturated = None
        self._t_now = t
        u = self._compute(q, qd, t, signals)
        if self.ki != 0.0:
            self._hold = self.anti_windup and self.saturation()
        return u

    def _distribute(self, hessian: np.ndarray, gradient: np.ndarray, servo_map=None) -> np.ndarray:
        """The bounded input (acroboter.control.distribution) into self.u; with `servo_map` (E),
        lexicographic in the servo accelerations E u (BoundedInputs.solve_task). With saturation as
        underactuation: the distribution's unbounded input is the full task's u*, the limits are met by
        holding inputs (_underactuate)."""
        try:
            if self.underactuation is not None:
                if servo_map is None:
                    u_star = self.limits.solve(hessian, gradient, unbounded_only=True)
                else:
                    u_star = self.limits.solve_task(hessian, gradient, servo_map, unbounded_only=True)
                self._underactuate(u_star)
            elif servo_map is None:
                self.u[:] = self.limits.solve(hessian, gradient)
            else:
                self.u[:] = self.limits.solve_task(hessian, gradient, servo_map)
        except DistributionError as err:
            raise SingularSystemError(f"{self.name}: {err}") from None
        return self.u

    def _underactuate(self, u_star: np.ndarray) -> bool:
        """Saturation as underactuation: True if the full task's input u* is the step's input (then, as with the
        QP, self.limits.accept took it: bit for bit today's step); else the reduced task's input into self.u
        (False), with limit_state marking the held inputs and u* kept as what the full task asked."""
        limits, under = self.limits, self.underactuation
        if under.full_task(u_star, self._t_now) and limits.accept(u_star):
            self.u[:] = u_star
            return True
        limits.unbounded[:] = u_star  # before self.u changes: the penalty methods' u* is that buffer
        self._servo_fn.call()  # E at the state and gains in the input buffers (again for MLM: the same values)
        servo_map = self._servo_fn.outputs["servo_map"]
        try:
            u = under.solve(servo_map, servo_map @ limits.unbounded)
        except FloatingPointError as err:
            raise SingularSystemError(f"{self.name}: saturation as underactuation: {err}") from None
        self.u[:] = u
        limits.u[:] = u
        limits.limit_state[:] = under.held
        limits.bounded_step = True
        return False

    def saturation(self) -> bool:
        """Did the limits keep the last compute() from what it asked of the task?

        A report, not part of the control step (call it right after compute(), at the same state):
        the servo-constraint accelerations a = E u* of the unbounded input u* (E = σ_q P H) are asked
        of the limits in a second bounded least squares, min |E u − a|²; saturated if even its best
        input misses a by more than SATURATION_TOLERANCE.
        """
        if self._saturated is not None:  # judged already for this step (the anti-windup asks first)
            return self._saturated
        self._saturated = self._judge_saturation()
        return self._saturated

    def _judge_saturation(self) -> bool:
        limits = self.limits
        if not limits.bounded_step:
            return False
        if self._servo_fn is not self._bounded_fn:
            self._servo_fn.call()  # at the state and gains still in the input buffers
        servo_map = self._servo_fn.outputs["servo_map"]
        asked = servo_map @ limits.unbounded
        try:
            best = self._judge.solve(servo_map.T @ servo_map, -(servo_map.T @ asked))
        except DistributionError:
            return True
        miss = np.abs(servo_map @ best - asked).max()
        return bool(miss > SATURATION_TOLERANCE * max(1.0, float(np.abs(asked).max())))

    def _load(self, q: np.ndarray, qd: np.ndarray, t: float, signals, function=None) -> None:
        """State, signals and gains into the input buffers, then one call of `function` (default: the terms)."""
        self._q[:] = q
        self._qd[:] = qd
        self._signals[:] = self.path.flat(t) if signals is None else signals
        if self.model.parameters_owner is not self:  # another controller may have set other gains
            self._p[:] = self._params
            self.model.parameters_owner = self
        if self.ki != 0.0 and self._integrate_in_load:
            self._integrate(t)
        (function or self._fn).call()

    def _compute(self, q: np.ndarray, qd: np.ndarray, t: float, signals) -> np.ndarray:
        raise NotImplementedError


class MLM(Controller):
    """Method of Lagrange multipliers (paper eq. 4).

    The (n+m+l) system [M φ_qᵀ −H; φ_q 0 0; σ_q 0 0] is reduced with the constant M to its Schur
    complement in (λ, u), (m+l) square, solved by LU with a condition estimate.
    """

    name = "mlm"
    terms_function = "mlm_terms"
    bounded_function = "mlm_bounded_terms"

    def __init__(self, model, path: DesiredPath, gains: Gains, limits=None):
        super().__init__(model, path, gains, limits)
        if self.k > self.l:
            raise SingularSystemError(
                f"MLM needs at least as many inputs as servo-constraints, found {self.k} servo-constraints for "
                f"{self.l} inputs (redundant task): its matrix is not square. Use the penalty or iterative "
                "penalty method."
            )
        self._gesv, self._gecon = lapack.get_lapack_funcs(("gesv", "gecon"), (self.terms["schur"],))
        self.rcond = np.nan
        self._y = np.zeros(self.m + self.l)
        self._y_current = True  # False when the applied u is not the Schur solution (limits, redundancy)

    def _compute(self, q, qd, t, signals):
        if self.redundant_inputs:
            # E u = e has a family of solutions (internal forces): the distribution picks one.
            self._load(q, qd, t, signals, self._bounded_fn)
            B = self.bounded_terms
            self._y_current = False
            return self._distribute(B["hessian"], B["gradient"])
        self._load(q, qd, t, signals)
        T = self.terms
        # One LU (gesv) for the solution, then LAPACK's condition estimate on the same factors.
        lu, _, y, info = self._gesv(T["schur"], T["schur_rhs"], overwrite_a=True, overwrite_b=True)
        self.rcond = self._gecon(lu, T["schur_norm1"][0])[0] if info == 0 else 0.0
        if info != 0 or self.rcond < MLM_RCOND_LIMIT:
            size = self.n + self.m + self.l
            raise SingularSystemError(
                f"MLM's {size}x{size} system is singular (reciprocal condition number {self.rcond:.1e}): the "
                "geometric constraints are redundant or the task is not reachable by the inputs. MLM needs "
                "independent constraints; use the penalty or iterative penalty method, which handle redundancy."
            )
        self._y = y
        self._y_current = True
        if self.underactuation is not None:
            self._y_current = self._underactuate(y[self.m :])
            return self.u
        if self.limits.accept(y[self.m :]):
            self.u[:] = y[self.m :]
            return self.u
        # A limit is in the way: the bounded input closest to realising the servo accelerations.
        self._y_current = False
        self._bounded_fn.call()
        B = self.bounded_terms
        return self._distribute(B["hessian"], B["gradient"])

    def _reactions(self) -> None:
        """y = [λ; u] for the applied u, when it is not the Schur solution: λ from the geometric rows,
        φ_q M⁻¹φ_qᵀ λ = rhs − φ_q M⁻¹(−H) u, the constrained dynamics under that u (φ_q q̈ + γ = 0). The servo
        rows are left out: a bounded u cannot meet them, and a least squares over all rows (as before)
        traded the constraints for them, φ_q q̈ + γ up to 3e-3 m/s² on the default crane."""
        if self._y_current:
            return
        self._fn.call()  # Schur terms at the state still in the buffers
        T, m = self.terms, self.m
        schur = T["schur"]
        rhs = T["schur_rhs"][:m] - schur[:m, m:] @ self.u
        self._y[:m] = np.linalg.solve(schur[:m, :m], rhs)
        self._y[m:] = self.u
        self._y_current = True

    @property
    def qdd(self) -> np.ndarray:
        """q̈ = −M⁻¹(c + W y) of the last step: the acceleration the method commands."""
        self._reactions()
        T = self.terms
        return -(T["minv_bias"] + T["minv_w"] @ self._y)

    @property
    def multipliers(self) -> tuple[np.ndarray, None]:
        self._reactions()
        return self._y[: self.m], None


class Penalty(Controller):
    """Penalty formulation (paper eqs. 8-13) and its iterative extension (eqs. 16-19).

    iterations = 1 is the plain penalty method: A q̈₁ = M q̈₀ − α̃ φ_qᵀρ − α̂ σ_qᵀρ_s with M q̈₀ = −c is
    exactly eq. 8. More iterations refine q̈ and the multipliers with the same factorization of A.
    """

    terms_function = "penalty_terms"
    bounded_function = "penalty_bounded_terms"
    secondary_weight = PENALTY_SECONDARY_WEIGHT  # eq12/eq13 with redundant inputs, where a limit is in the way

    def __init__(self, model, path: DesiredPath, gains: Gains, iterations: int = 1, limits=None):
        if gains.recovery in ("projected", "kinetic"):
            # Redundant inputs: lexicographic in the servo accelerations (BoundedInputs.solve_task), as MLM.
            self.secondary_weight = 0.0
        super().__init__(model, path, gains, limits)
        if iterations < 1:
            raise ValueError("iterations must be at least 1")
        self.iterations = iterations
        self.name = "penalty" if iterations == 1 else f"iterative-{iterations}"
        n = self.n
        # M is constant in natural coordinates (acroboter.codegen.solver_terms checks it): take it once.
        self.mass = model.term("mass_matrix").copy()
        self._qdd_sum = np.zeros(n)
        self._qdd_last = np.zeros(n)
        self._potrf, self._potrs = lapack.get_lapack_funcs(("potrf", "potrs"), (self.mass,))
        redundant = set(model.layout.redundant_rows)
        rows = [i for i in range(self.m) if i not in redundant]
        self.recovery = InputRecovery(gains.recovery, self.mass, self.k, self.l, gains.kappa, rows)
        self.u = self.recovery.u  # the recovery writes the input in place: one buffer, no copy
        if iterations > 1:
            # Iterations 2..N: two bindings of the generated update read each other's outputs, so the
            # chain runs without copies; both read the factor and force where penalty_terms left them.
            first, second = model.bind("penalty_iteration"), model.bind("penalty_iteration")
            for this, other in ((first, second), (second, first)):
                this.point_input(0, self.terms["penalty_matrix"].ctypes.data)
                this.point_input(1, self.terms["penalty_force"].ctypes.data)
                this.point_input(2, other.outputs["qdd_next"].ctypes.data)
                this.point_input(3, other.outputs["qdd_sum_next"].ctypes.data)
            self._chain = [first.call if i % 2 == 0 else second.call for i in range(iterations - 1)]
            self._chain_start = second.outputs  # the first call reads these
            self._chain_end = (first if (iterations - 1) % 2 == 1 else second).outputs
        self.fast_recovery = gains.recovery == "projected"
        self._gradient = np.zeros(self.l)

    def _compute(self, q, qd, t, signals):
        self._load(q, qd, t, signals)
        T = self.terms
        chol, info = self._potrf(T["penalty_matrix"], lower=False, overwrite_a=True, clean=False)
        if info != 0:
            raise SingularSystemError(
                "the penalty matrix A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q is not positive definite "
                f"(LAPACK potrf info {info}): check the penalty numbers"
            )
        if chol is not T["penalty_matrix"]:  # LAPACK factored a copy: the iterations read the buffer
            T["penalty_matrix"][...] = chol
        # i = 0: M q̈₀ = −c, so the first right-hand side is −c + force (no solve for q̈₀).
        x, _ = self._potrs(chol, T["penalty_rhs"], lower=False)
        if self.iterations == 1:
            self._qdd_sum = self._qdd_last = x
        else:  # A q̈_{i+1} = M q̈_i + force, i = 1..N−1, with the same factor (generated solves)
            self._chain_start["qdd_next"][:] = x
            self._chain_start["qdd_sum_next"][:] = x
            for call in self._chain:
                call()
            self._qdd_last = self._chain_end["qdd_next"]
            self._qdd_sum = self._chain_end["qdd_sum_next"]
        if self.redundant_inputs and self.fast_recovery:
            return self._bounded_projected()  # the fit leaves internal forces free: distribute them
        if self.redundant_inputs and self.recovery.kind == "kinetic":  # the same, with the whole acceleration's fit
            self._multipliers()
            fit = self.recovery.least_squares(T, self.lam_hat, self._qdd_last, self.lam)
            self._servo_fn.call()  # E at the state penalty_terms just read
            return self._distribute(*fit, self._servo_fn.outputs["servo_map"])
        fast = self.fast_recovery and self.recovery.projected_fast(T, self._qdd_sum, self.iterations) is not None
        if not fast:  # another recovery, or the generated projected map was singular
            self._multipliers()
            if self.fast_recovery:
                self._bounded_fn.call()  # the projected fit's terms at the state penalty_terms just read
            self.recovery.recover(T, self.lam_hat, self._qdd_last, self.lam, self.bounded_terms)
        if self.underactuation is not None:
            self._underactuate(self.u)
            return self.u
        if self.limits.accept(self.u):
            return self.u
        # A limit is in the way: the same fit, bounded.
        if self.fast_recovery:
            return self._bounded_projected()
        self._multipliers()
        return self._distribute(*self.recovery.least_squares(T, self.lam_hat, self._qdd_last, self.lam))

    def _bounded_projected(self) -> np.ndarray:
        """The projected recovery's fit ½uᵀGu + gᵀu, g = servo_map · λ̂, within the limits.

        With redundant inputs the fit's task part exactly and the internal forces (the null space of
        the servo accelerations E = σ_q P H, from mlm_bounded_terms) at the preferred values: see
        acroboter.control.distribution (BoundedInputs.solve_task)."""
        self._bounded_fn.call()  # at the state and parameters penalty_terms just read
        self._multipliers()
        B = self.bounded_terms
        np.matmul(B["servo_map"], self.lam_hat, out=self._gradient)
        if self.redundant_inputs:
            self._servo_fn.call()  # E at the same state
            return self._distribute(B["hessian"], self._gradient, self._servo_fn.outputs["servo_map"])
        return self._distribute(B["hessian"], self._gradient)

    def _multipliers(self) -> None:
        """λ̂_N = Σ α̂(σ_q q̈_i + ρ_s) over the N iterations (eq. 18 summed), likewise λ_N (eq. 17)."""
        T, g, N = self.terms, self.gains, float(self.iterations)
        np.matmul(T["sigma_q"], self._qdd_sum, out=self.lam_hat)
        self.lam_hat += N * T["rho_s"]
        self.lam_hat *= g.alpha_servo
        np.matmul(T["phi_q"], self._qdd_sum, out=self.lam)
        self.lam += N * T["rho"]
        self.lam *= g.alpha_geometric

    @property
    def qdd(self) -> np.ndarray:
        """The last step's commanded acceleration q̈_N."""
        return self._qdd_last

    @property
    def multipliers(self) -> tuple[np.ndarray, np.ndarray]:
        """(λ, λ̂) of the last step (computed on demand: the default recovery does not need them)."""
        self._multipliers()
        return self.lam, self.lam_hat


def make_controller(method: str, model, path: DesiredPath, gains: Gains, limits=None, fast: bool = False):
    """'mlm', 'penalty' or 'iterative-N'; `limits` (min, max, preferred) default to the spec's.

    fast=True: the fast path (acroboter.control.fast_path: one compiled function per step, generated and compiled on
    first use) around this reference controller; where it cannot be built, the reference itself, its
    `fast_refusal` saying why."""
    if fast:
        from .fast_path import make_fast

        return make_fast(make_controller(method, model, path, gains, limits), method)
    if method == "mlm":
        return MLM(model, path, gains, limits)
    if method == "penalty":
        return Penalty(model, path, gains, iterations=1, limits=limits)
    if method.startswith("iterative-") and method.removeprefix("iterative-").isdigit():
        return Penalty(model, path, gains, iterations=int(method.removeprefix("iterative-")), limits=limits)
    raise ValueError(f"unknown method '{method}': use mlm, penalty or iterative-N (N >= 1)")
