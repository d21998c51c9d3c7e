"""Oracles for the control laws themselves (issue 19), computed with numpy from the model's terms
(`model_terms`: M, c, φ, φ_q, φ̇, γ, σ, σ_q, σ̇, γ_s, H from the symbolic model), never through a
controller's generated terms (codegen/solver_terms.py) or its recovery code.

(a) At recorded states of each method's closed loop on the default crane: MLM's input, put through
    the constrained dynamics (a dense KKT solve), gives σ̈ = −2k_D σ̇ − k_P² σ − k_I z to rounding;
    the penalty methods' commanded q̈ gives it to O(1/α) (plain penalty: the defect scales as 1/α,
    measured at α and 10α), the iterative ones to rounding. z is the trapezoid of the recorded σ.
(b) Off the manifold (the plant started 1 mm and 1 mm/s off its constraints, and a plant whose main
    cable is 1 mm longer than the model's): the plant's φ(t) is the critically damped solution of
    φ̈ + 2ζ_B ω_B φ̇ + ω_B² φ = 0; the penalty methods command φ_q q̈ + γ = −(2Ωμ φ̇ + Ω² φ) to O(1/α);
    MLM commands φ_q q̈ + γ = 0.
(c) Every input recovery against its defining equation on a toy whose actuators load the
    constraint directions (tests/specs/loaded_toy.toml: Hᵀφ_qᵀλ ≠ 0, so eq. 13's multiplier term
    matters).
(d) The α-β velocity filter against its own recursion in numpy, with gains from its poles.

Every check also asserts that the term it guards is not negligible at the states it uses, so that
a law with a wrong gain (k_P for k_P², Ω for Ω², half the plant's damping, ...) fails it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import build_in, load_with_start

from acroboter.control.controllers import Gains, make_controller
from acroboter.model.spec import load_spec
from acroboter.sim.plant import Plant
from acroboter.sim.sensing import Estimator, resolve
from acroboter.sim.simulation import setup_default, simulate

REPO = Path(__file__).resolve().parent.parent
TOY = Path(__file__).resolve().parent / "specs" / "loaded_toy.toml"
METHODS = ("mlm", "penalty", "iterative-3")
INSTANTS = (10, 25, 50, 100, 150, 200)  # recorded instants the laws are checked at (50 Hz: 0.2 … 4 s)
KI = 18.375  # tests/test_integral_action.py's: the integrator's pole at -1.5 with k_P = k_D = 5


@pytest.fixture(scope="module")
def crane():
    return load_with_start(REPO / "model_spec" / "acroboter.toml")


def terms(model, path, q, qd, t) -> dict:
    s, sd, sdd = path.signal_arrays(t)
    return {k: np.array(v, copy=True) for k, v in model.evaluate("model_terms", q, qd, s, sd, sdd).items()}


def constrained_acceleration(T: dict, u: np.ndarray, geometric: np.ndarray) -> np.ndarray:
    """q̈ of [M φ_qᵀ; φ_q 0][q̈; λ] = [H u − c; geometric] (least squares: q̈ is unique even where λ is not)."""
    mass, phi_q = T["mass_matrix"], T["phi_q"]
    n, m = mass.shape[0], phi_q.shape[0]
    kkt = np.block([[mass, phi_q.T], [phi_q, np.zeros((m, m))]])
    rhs = np.concatenate([T["input_matrix"] @ u - T["bias_forces"], geometric])
    return np.linalg.lstsq(kkt, rhs, rcond=None)[0][:n]


def servo_law(T: dict, gains: Gains, z=0.0) -> np.ndarray:
    """The tracking error dynamics' right-hand side: σ̈ = −2k_D σ̇ − k_P² σ − k_I z."""
    return -(2 * gains.kd * T["sigma_dot"] + gains.kp**2 * T["sigma"] + gains.ki * z)


def constraint_law(T: dict, gains: Gains) -> np.ndarray:
    """The penalty methods' constraint dynamics: φ̈ = −2Ωμ φ̇ − Ω² φ."""
    return -(2 * gains.omega * gains.mu * T["phi_dot"] + gains.omega**2 * T["phi"])


def run(crane, method, duration=4.0, gains=None, q0=None, qd0=None, plant=None):
    spec, model, path, start = crane
    controller = make_controller(method, model, path, gains or Gains.from_spec(spec))
    plant = plant or setup_default(model, path)
    result = simulate(model, path, controller, plant, start.q if q0 is None else q0, duration,
                      spec.controller.rate_hz, spec.simulation.step, qd0=qd0)
    return result, controller


@pytest.fixture(scope="module")
def tracking_runs(crane):
    return {method: run(crane, method)[0] for method in METHODS}


# --- (a) the servo-constraint law -------------------------------------------------------------------------

def test_mlm_input_realizes_the_servo_law_exactly(crane, tracking_runs):
    spec, model, path, _ = crane
    gains = Gains.from_spec(spec)
    r = tracking_runs["mlm"]
    for k in INSTANTS:
        T = terms(model, path, r.q[k], r.qd[k], r.t[k])
        qdd = constrained_acceleration(T, r.u[k], -T["gamma"])  # MLM's own constraint rows: φ̈ = 0
        sigma_ddot = T["sigma_q"] @ qdd + T["gamma_s"]
        law = servo_law(T, gains)
        scale = np.abs(sigma_ddot).max() + np.abs(law).max()
        np.testing.assert_allclose(sigma_ddot, law, rtol=0, atol=1e-9 * scale)
        # k_P² σ is seen: k_P σ in its place would miss by far more than the tolerance
        assert np.abs((gains.kp**2 - gains.kp) * T["sigma"]).max() > 1e4 * 1e-9 * scale


@pytest.mark.parametrize("method", ["penalty", "iterative-3"])
def test_penalty_commanded_acceleration_meets_the_servo_law_to_order_one_over_alpha(crane, tracking_runs, method):
    """The plain penalty's defect σ̈ − law is λ̂/α̂: ten times smaller at ten times α. Three
    iterations leave (‖…‖/α)³: rounding."""
    spec, model, path, _ = crane
    gains = Gains.from_spec(spec)
    r = tracking_runs[method]
    for k in INSTANTS:
        T = terms(model, path, r.q[k], r.qd[k], r.t[k])
        law = servo_law(T, gains)
        defects = []
        for alpha in (gains.alpha_servo, 10 * gains.alpha_servo):
            controller = make_controller(method, model, path, Gains.from_spec(spec, alpha_servo=alpha,
                                                                              alpha_geometric=alpha))
            controller.compute(r.q[k], r.qd[k], r.t[k])
            defects.append(T["sigma_q"] @ controller.qdd + T["gamma_s"] - law)
        scale = np.abs(law).max() + np.abs(T["sigma_q"] @ controller.qdd + T["gamma_s"]).max()
        kp_term = np.abs((gains.kp**2 - gains.kp) * T["sigma"]).max()
        if method == "penalty":
            worst = np.abs(defects[0]).max()
            # O(1/α): the defect is λ̂/α̂, λ̂ about the SU's weight (78.5 N): 7.85e-6 m/s² at α̂ = 1e7
            assert 1e-9 < worst < 1.2 * 78.5 / gains.alpha_servo
            ratio = worst / np.abs(defects[1]).max()
            assert ratio == pytest.approx(10.0, rel=0.02)  # the measured α-dependence: 1/α
            # extrapolated to α → ∞ (Richardson on the 1/α term) the law holds to rounding, and
            # k_P σ for k_P² σ would leave (k_P² − k_P) σ there
            limit = np.abs(10 * defects[1] - defects[0]).max() / 9
            assert limit < 1e-3 * worst
            assert kp_term > 100 * limit + 0.1 * worst
        else:
            assert np.abs(defects[0]).max() < 1e-10 * scale
            assert kp_term > 1e6 * 1e-10 * scale


def test_the_integral_is_the_trapezoid_of_the_recorded_sigma_and_enters_the_law(crane):
    """z after each step against numpy's trapezoid of σ at the recorded instants; MLM with k_I ≠ 0
    realizes σ̈ = −2k_D σ̇ − k_P² σ − k_I z with that z."""
    spec, model, path, _ = crane
    gains = Gains.from_spec(spec, ki=KI)
    r, _ = run(crane, "mlm", duration=3.0, gains=gains)
    assert not r.saturated.any()  # no anti-windup hold: z is the plain integral
    dt = np.diff(r.t)[:, None]
    trapezoid = np.vstack([np.zeros(r.sigma.shape[1]), np.cumsum(0.5 * dt * (r.sigma[1:] + r.sigma[:-1]), axis=0)])
    replay = make_controller("mlm", model, path, gains)  # z depends only on the states it is given
    for k in range(len(r.t)):
        u = replay.compute(r.q[k], r.qd[k], r.t[k])
        z = replay.integral
        scale = np.abs(trapezoid[k]).max() + 1e-12
        np.testing.assert_allclose(z, trapezoid[k], rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(u, r.u[k], rtol=1e-9, atol=1e-9)
        if k in INSTANTS:
            T = terms(model, path, r.q[k], r.qd[k], r.t[k])
            qdd = constrained_acceleration(T, r.u[k], -T["gamma"])
            sigma_ddot = T["sigma_q"] @ qdd + T["gamma_s"]
            law = servo_law(T, gains, z)
            tol = 1e-9 * (np.abs(sigma_ddot).max() + np.abs(law).max())
            np.testing.assert_allclose(sigma_ddot, law, rtol=0, atol=tol)
            assert gains.ki * np.abs(z).max() > 1e4 * tol  # the integral term is seen
    # the rectangle rule differs from the trapezoid by T/2 (σ_k − σ_0): far above the tolerance
    assert np.abs(0.5 * dt[0, 0] * (r.sigma[-1] - r.sigma[0])).max() > 1e3 * 1e-9 * np.abs(trapezoid[-1]).max()


# --- (b) off the manifold -----------------------------------------------------------------------------------

class OffManifoldPlant(Plant):
    """The own plant without its energy check: off the manifold the Baumgarte forces do work λᵀφ_q q̇
    that the balance (an on-manifold invariant) does not account for; nor does it refine its step on the
    balance (acroboter.sim.plant_refinement), for the same reason."""

    def _check_energy(self, x, t, residual=None):
        self.energy_residual = 0.0

    def _period_holds(self, x, duration):
        self._period_residual = 0.0
        return True


def off_manifold_start(crane):
    """The static start with the SU 1 mm low (its three cables stretched 1 mm, sinking at 1 mm/s) and its
    u axis 1 mm too long: cable rows and a body row off φ = 0."""
    spec, model, path, start = crane
    lay = model.layout
    su = lay.body_offset["SU"]
    q0, qd0 = start.q.copy(), np.zeros(lay.n)
    q0[su + 2] -= 1e-3
    qd0[su + 2] -= 1e-3
    q0[su + 3] += 1e-3
    return q0, qd0


@pytest.fixture(scope="module")
def off_manifold_runs(crane):
    spec, model, path, _ = crane
    q0, qd0 = off_manifold_start(crane)
    sim = spec.simulation
    return {method: run(crane, method, 1.0, q0=q0, qd0=qd0,
                        plant=OffManifoldPlant(model, path, sim.baumgarte_zeta, sim.baumgarte_omega))
            for method in ("mlm", "penalty", "iterative-3")}


def damped(phi0, phid0, zeta, omega, t):
    """The solution of φ̈ + 2ζω φ̇ + ω² φ = 0 from (φ0, φ̇0), per row (ζ = 1 or ζ < 1)."""
    t = np.asarray(t)[:, None]
    if zeta == 1.0:
        return (phi0 + (phid0 + omega * phi0) * t) * np.exp(-omega * t)
    wd = omega * np.sqrt(1 - zeta**2)
    return np.exp(-zeta * omega * t) * (phi0 * np.cos(wd * t) + (phid0 + zeta * omega * phi0) / wd * np.sin(wd * t))


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
def test_plant_constraints_follow_the_critically_damped_solution(crane, off_manifold_runs, method):
    spec, model, path, _ = crane
    sim = spec.simulation
    assert (sim.baumgarte_zeta, sim.baumgarte_omega) == (1.0, 20.0)
    r, _ = off_manifold_runs[method]
    assert r.cable_active.all() and r.cable_tension.min() > 0  # every cable stays taut: the rows hold
    T0 = terms(model, path, r.q[0], r.qd[0], 0.0)
    phi0, phid0 = T0["phi"], T0["phi_dot"]
    size = np.abs(phi0).max()
    assert size > 1e-3 and np.abs(phid0).max() > 1e-3  # 1 mm and 1 mm/s off
    expected = damped(phi0, phid0, sim.baumgarte_zeta, sim.baumgarte_omega, r.t)
    # RK4 at ω_B h = 0.04 follows the linear constraint dynamics to ~3e-8 of φ0
    np.testing.assert_allclose(r.phi, expected, rtol=0, atol=1e-6 * size)
    # the check tells damping apart: half of it (ζ = 0.5) is 30 % of φ0 away
    half = damped(phi0, phid0, 0.5, sim.baumgarte_omega, r.t)
    assert np.abs(half - expected).max() > 0.1 * size


def check_constraint_law(crane, method, r, instants):
    """At the recorded instants, the commanded q̈ against φ_q q̈ + γ = −(2Ωμ φ̇ + Ω² φ) (numpy). Plain
    penalty: the defect is λ/α̃, ten times smaller at ten times α, and Richardson's α → ∞ limit of it
    is rounding; iterative-3: rounding. Ω² φ, not Ω φ: the difference is far above what is left."""
    spec, model, path, _ = crane
    gains = Gains.from_spec(spec)
    for k in instants:
        T = terms(model, path, r.q[k], r.qd[k], r.t[k])
        law = constraint_law(T, gains)
        defects = []
        for scale in (1.0, 10.0):
            controller = make_controller(method, model, path, Gains.from_spec(
                spec, alpha_geometric=scale * gains.alpha_geometric, alpha_servo=scale * gains.alpha_servo))
            controller.compute(r.q[k], r.qd[k], r.t[k])
            defects.append(T["phi_q"] @ controller.qdd + T["gamma"] - law)
        omega_term = np.abs((gains.omega**2 - gains.omega) * T["phi"]).max()
        if method == "penalty":
            worst = np.abs(defects[0]).max()
            assert worst < 1e-5  # λ/α̃: 3.3e-6 seen (cable forces of tens of N over 1e7)
            assert worst / np.abs(defects[1]).max() == pytest.approx(10.0, rel=0.02)
            limit = np.abs(10 * defects[1] - defects[0]).max() / 9
            assert limit < 1e-3 * worst
        else:
            limit = np.abs(defects[0]).max()
            assert limit < 1e-9 * np.abs(law).max()
        assert omega_term > 1e3 * limit


@pytest.mark.parametrize("method", ["penalty", "iterative-3"])
def test_penalty_commands_its_constraint_dynamics_off_the_manifold(crane, off_manifold_runs, method):
    r, _ = off_manifold_runs[method]
    check_constraint_law(crane, method, r, (0, 2, 5, 10, 20))


def test_mlm_commands_no_constraint_stabilisation(crane, off_manifold_runs):
    """MLM's constraint rows are φ̈ = 0 (φ_q q̈ = −γ): only the plant's Baumgarte term brings φ back."""
    spec, model, path, _ = crane
    r, controller = off_manifold_runs["mlm"]
    for k in (0, 5, 20):
        T = terms(model, path, r.q[k], r.qd[k], r.t[k])
        qdd = constrained_acceleration(T, r.u[k], -T["gamma"])
        np.testing.assert_allclose(T["phi_q"] @ qdd + T["gamma"], 0.0, atol=1e-10)
        law = servo_law(T, Gains.from_spec(spec))
        sigma_ddot = T["sigma_q"] @ qdd + T["gamma_s"]
        np.testing.assert_allclose(sigma_ddot, law, rtol=0, atol=1e-9 * (np.abs(law).max() + np.abs(sigma_ddot).max()))


@pytest.mark.parametrize("method", ["penalty", "iterative-3"])
def test_geometry_mismatch_keeps_the_penalty_constraint_term_acting(crane, method):
    """The plant's main cable 1 mm longer than the model's: the model's φ stays off zero all run, and at
    every checked instant the commanded q̈ meets φ̈ = −2Ωμ φ̇ − Ω² φ with the model's φ."""
    spec, model, path, _ = crane
    length = next(c for c in spec.cables if c.name == "main").length
    plant = setup_default(model, path, {"main.length": length + 1e-3})
    r, _ = run(crane, method, 2.0, plant=plant)
    row = model.layout.constraints.index("cable main")
    assert np.abs(r.phi[10:, row]).min() > 1e-3  # the model's φ of the main cable: |d|² − L² ≈ 2 L · 1 mm
    check_constraint_law(crane, method, r, (10, 50, 100))


# --- (c) the input recoveries -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return build_in(tmp_path_factory.mktemp("loaded_toy"), load_spec(TOY))


def toy_states(toy, count=3, seed=11):
    """States on the toy's manifold at random attitudes and rates along the path."""
    spec, model, path = toy
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        rot, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        rot *= np.sign(np.linalg.det(rot))
        omega, t = rng.standard_normal(3), rng.uniform(0.0, path.duration)
        q = np.concatenate([path.position(t)[0] + 0.01 * rng.standard_normal(3), rot.T.reshape(-1)])
        qd = np.concatenate([0.1 * rng.standard_normal(3), *(np.cross(omega, rot[:, k]) for k in range(3))])
        out.append((q, qd, t))
    return out


def penalty_in_numpy(T: dict, gains: Gains, iterations: int):
    """(q̈_N, λ_N, λ̂_N) of the (iterative) penalty method, eqs. 8 and 16-19, from the model's terms:
    A q̈_{i+1} = M q̈_i − α̃ φ_qᵀρ − α̂ σ_qᵀρ_s from M q̈_0 = −c; λ_N = α̃ Σ_i (φ_q q̈_i + ρ), likewise λ̂."""
    mass, phi_q, sigma_q = T["mass_matrix"], T["phi_q"], T["sigma_q"]
    rho = T["gamma"] - constraint_law(T, gains)
    rho_s = T["gamma_s"] - servo_law(T, gains)
    a, b = gains.alpha_geometric, gains.alpha_servo
    matrix = mass + a * phi_q.T @ phi_q + b * sigma_q.T @ sigma_q
    force = -a * phi_q.T @ rho - b * sigma_q.T @ rho_s
    qdd = np.linalg.solve(mass, -T["bias_forces"])
    total = np.zeros_like(qdd)
    for _ in range(iterations):
        qdd = np.linalg.solve(matrix, mass @ qdd + force)
        total += qdd
    lam = a * (phi_q @ total + iterations * rho)
    lam_hat = b * (sigma_q @ total + iterations * rho_s)
    return qdd, lam, lam_hat


def expected_input(kind: str, T: dict, mass: np.ndarray, qdd, lam, lam_hat, kappa: float) -> np.ndarray:
    """Each recovery's defining equation (control/recovery.py's docstring), solved with numpy."""
    H, phi_q, sigma_q = T["input_matrix"], T["phi_q"], T["sigma_q"]
    servo_force = sigma_q.T @ lam_hat
    pinv = np.linalg.pinv(H)
    if kind == "eq12":  # min |H u + σ_qᵀλ̂|
        return -pinv @ servo_force
    if kind == "eq13":  # min |H u − (M q̈ + c + φ_qᵀλ)|
        return pinv @ (mass @ qdd + T["bias_forces"] + phi_q.T @ lam)
    if kind == "eq15":
        return lam_hat.copy()
    if kind == "kappa":
        return -(kappa * pinv - (1 - kappa) * sigma_q) @ servo_force
    if kind == "kinetic":
        # min over (u, Δλ) of |H u − φ_qᵀΔλ + σ_qᵀλ̂| in the M⁻¹ metric, WᵀW = M⁻¹
        weight = np.linalg.cholesky(np.linalg.inv(mass)).T
        stacked = np.hstack([H, -phi_q.T])
        return np.linalg.lstsq(weight @ stacked, -(weight @ servo_force), rcond=None)[0][: H.shape[1]]
    # projected: the inputs that accelerate the servo outputs as the ideal servo force does, each acceleration from
    # the constrained dynamics [M φ_qᵀ; φ_q 0][a; λ] = [f; 0]
    n, m = mass.shape[0], phi_q.shape[0]
    kkt = np.block([[mass, phi_q.T], [phi_q, np.zeros((m, m))]])
    forces = np.hstack([H, servo_force[:, None]])
    accelerations = np.linalg.lstsq(kkt, np.vstack([forces, np.zeros((m, forces.shape[1]))]), rcond=None)[0][:n]
    servo = sigma_q @ accelerations
    return np.linalg.lstsq(servo[:, :-1], -servo[:, -1], rcond=None)[0]


def test_the_toys_actuators_load_its_constraint_directions(toy):
    spec, model, path = toy
    gains = Gains.from_spec(spec)
    for q, qd, t in toy_states(toy):
        T = terms(model, path, q, qd, t)
        _, lam, _ = penalty_in_numpy(T, gains, 1)
        H = T["input_matrix"]
        assert np.abs(H.T @ T["phi_q"].T @ lam).max() > 1e-2 * np.abs(H.T @ H).max()
        assert not np.allclose(H, -T["sigma_q"].T, atol=1e-3)  # not collocated either


@pytest.mark.parametrize("iterations", [1, 3])
@pytest.mark.parametrize("kind", ["projected", "kinetic", "eq12", "eq13", "eq15", "kappa"])
def test_each_recovery_meets_its_defining_equation(toy, kind, iterations):
    spec, model, path = toy
    # κ = 0.3, not the default 0.5: a κ lost on the way to the recovery would give the default's blend
    gains = Gains.from_spec(spec, recovery=kind, kappa=0.3 if kind == "kappa" else None)
    method = "penalty" if iterations == 1 else f"iterative-{iterations}"
    controller = make_controller(method, model, path, gains)
    for q, qd, t in toy_states(toy):
        T = terms(model, path, q, qd, t)
        qdd, lam, lam_hat = penalty_in_numpy(T, gains, iterations)
        expected = expected_input(kind, T, T["mass_matrix"], qdd, lam, lam_hat, gains.kappa)
        u = controller.compute(q, qd, t)
        np.testing.assert_allclose(u, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())
        if kind == "eq13":  # the multiplier term moves u by far more than the tolerance
            shift = np.linalg.pinv(T["input_matrix"]) @ (T["phi_q"].T @ lam)
            assert np.abs(shift).max() > 1e3 * 1e-6 * np.abs(expected).max()


@pytest.mark.parametrize("iterations", [1, 3])
@pytest.mark.parametrize("system", ["toy", "turning_toy"])
def test_the_projected_recoverys_fallback_meets_its_defining_equation(request, system, iterations, monkeypatch):
    """Where the generated projected map comes out singular (non-finite), recover() solves the same fit by a
    pivoted QR of its normal equations (recovery.py). With the map made to fail, u is still the servo
    accelerations' fit, solved with numpy from a numpy penalty solve and the constrained dynamics: on the loaded
    toy, and on the turning toy, whose body has products of inertia, so that its M is not diagonal (the loaded
    toy's and the crane's are: a term that reads M as diagonal goes unseen there)."""
    spec, model, path = request.getfixturevalue(system)
    gains = Gains.from_spec(spec, recovery="projected")
    controller = make_controller("penalty" if iterations == 1 else f"iterative-{iterations}", model, path, gains)
    monkeypatch.setattr(controller.recovery, "projected_fast", lambda *args: None)  # as a singular map returns
    for q, qd, t in toy_states((spec, model, path)):
        T = terms(model, path, q, qd, t)
        mass = T["mass_matrix"]
        if system == "turning_toy":
            assert np.abs(mass - np.diag(np.diag(mass))).max() > 1e-2 * np.abs(np.diag(mass)[3:]).min()
        qdd, lam, lam_hat = penalty_in_numpy(T, gains, iterations)
        expected = expected_input("projected", T, mass, qdd, lam, lam_hat, gains.kappa)
        u = controller.compute(q, qd, t)
        np.testing.assert_allclose(u, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())


@pytest.fixture(scope="module")
def turning_toy(tmp_path_factory):
    """The loaded toy with its thrust along v replaced by a torque about v: that torque's generalized force and
    thrust_x's both act on the w axis' coordinates, so HᵀH is not diagonal (with thrusters alone, along the
    body's axes, it is: their generalized forces are orthogonal wherever they act). Three inputs for three
    servo-constraints, as eq15 and κ need; the task's v direction is not actuated, which no recovery minds.
    Its body has products of inertia, so its mass matrix is not diagonal either."""
    root = tmp_path_factory.mktemp("turning_toy")
    inertia = "inertia = [[0.05, 0.0, 0.0], [0.0, 0.06, 0.0], [0.0, 0.0, 0.08]]"
    text = TOY.read_text().replace('name = "loaded_toy"', 'name = "turning_toy"')
    assert inertia in text
    text = text.replace(inertia, "inertia = [[0.05, 0.012, -0.008], [0.012, 0.06, 0.01], [-0.008, 0.01, 0.08]]")
    thrust_y = ('name = "thrust_y"\nkind = "body_thrust"\nbody = "box"\naxis = "v"\npoint = [0.0, 0.0, 0.2]\n'
                'gain = -1.0\n')
    assert thrust_y in text
    text = text.replace(thrust_y, 'name = "torque_v"\nkind = "body_torque"\nbody = "box"\naxis = "v"\n')
    (root / "turning_toy.toml").write_text(text)
    return build_in(root, load_spec(root / "turning_toy.toml"))


@pytest.mark.parametrize("kind", ["eq12", "eq13", "eq15", "kappa"])
def test_a_bounded_recovery_is_its_own_fit_within_the_limits(turning_toy, kind):
    """With the limit of the input each asks most of moved 5 % inside it: eq12 and eq13 stay their least squares in
    H u (scipy's lsq_linear of the step's own λ̂, or q̈ and λ), eq15 and κ, explicit maps, give the input within the
    limits nearest theirs (the box projection). On the turning toy HᵀH is not diagonal, so the two answers differ
    by far more than the tolerance and a recovery bounded by the other's rule fails (on the crane and the loaded
    toy they coincide)."""
    from scipy.optimize import lsq_linear

    least_squares = kind in ("eq12", "eq13")
    spec, model, path = turning_toy
    gains = Gains.from_spec(spec, recovery=kind, kappa=0.3 if kind == "kappa" else None)
    _, _, preferred = spec.input_limits()
    for q, qd, t in toy_states((spec, model, path)):
        free = make_controller("penalty", model, path, gains).compute(q, qd, t).copy()
        i = int(np.argmax(np.abs(free)))
        span = 10 * np.abs(free).max()
        low, high = np.full(free.size, -span), np.full(free.size, span)
        side = 1 if free[i] > 0 else -1
        (high if side > 0 else low)[i] = 0.95 * free[i]
        controller = make_controller("penalty", model, path, gains, limits=(low, high, preferred))
        u = controller.compute(q, qd, t).copy()
        lam, lam_hat = (np.array(a, copy=True) for a in controller.multipliers)
        T = terms(model, path, q, qd, t)
        H = T["input_matrix"]
        if kind == "eq13":
            target = T["mass_matrix"] @ controller.qdd + T["bias_forces"] + T["phi_q"].T @ lam
        else:
            target = -(T["sigma_q"].T @ lam_hat)
        fit = lsq_linear(H, target, bounds=(low, high), tol=1e-14, method="bvls", max_iter=1000).x
        nearest = np.clip(free, low, high)
        best, other = (fit, nearest) if least_squares else (nearest, fit)
        tolerance = 1e-7 * np.abs(best).max()
        assert u[i] == pytest.approx(0.95 * free[i], abs=1e-9) and controller.limit_state[i] == side
        np.testing.assert_allclose(u, best, rtol=0, atol=tolerance)
        assert np.abs(best - other).max() > 100 * tolerance  # the other rule would fail


# --- (d) the α-β velocity filter ----------------------------------------------------------------------------

def test_alpha_beta_filter_is_its_recursion_with_both_poles_at_the_design_pole(crane, tracking_runs):
    """On a recorded run with 0.2 mm noise on every coordinate: the estimator's q̇ is, to rounding, the
    α-β recursion x⁻ = x + T v, r = q̂ − x⁻, x = x⁻ + α r, v += (β/T) r on its projected positions q̂,
    then put onto φ_q q̇ = −φ_t, with α = 1 − p², β = (1 − p)², p = exp(−T/τ)."""
    spec, model, path, _ = crane
    sensing = resolve(spec, {"noise": {"positions": 2e-4, "axes": 2e-4, "lengths": 2e-4}, "seed": 3})
    estimator = Estimator(model, path, sensing)
    T = estimator.period
    pole = np.exp(-T / sensing.velocity_filter_s)
    alpha, beta = 1 - pole**2, (1 - pole) ** 2
    transition = np.array([[1 - alpha, T * (1 - alpha)], [-beta / T, 1 - beta]])  # error recursion
    np.testing.assert_allclose(np.linalg.eigvals(transition), [pole, pole], atol=1e-6)
    r = tracking_runs["mlm"]
    estimator.reset(r.q[0])
    xf = vf = None
    for k in range(60):
        q_hat, qd_hat = (a.copy() for a in estimator.estimate(r.q[k], r.t[k]))
        if xf is None:
            xf, vf = q_hat.copy(), np.zeros_like(q_hat)
        else:
            xf = xf + T * vf
            res = q_hat - xf
            xf = xf + alpha * res
            vf = vf + beta / T * res
        Tk = terms(model, path, q_hat, vf, r.t[k])
        a = Tk["phi_q"]
        expected = vf - a.T @ np.linalg.solve(a @ a.T, Tk["phi_dot"])
        np.testing.assert_allclose(qd_hat, expected, rtol=0, atol=1e-9 * max(1e-3, np.abs(expected).max()))
    assert np.abs(vf).max() > 1e-3  # the noise moves the estimate: the gains are exercised


def test_the_laws_hold_with_gains_that_are_not_the_critical_ones(crane, tracking_runs, off_manifold_runs):
    """The spec's gains are critical (k_D = k_P, μ = 1), where k_D in place of k_P or Ω/μ in place of Ωμ
    change nothing: with k_D = 3 ≠ k_P = 5 and μ = 0.6, at the recorded states (on and off the manifold),
    MLM's input realizes σ̈ = −2k_D σ̇ − k_P² σ exactly and iterative-3 commands
    φ_q q̈ + γ = −(2Ωμ φ̇ + Ω² φ) to rounding (both in numpy from the model's terms)."""
    spec, model, path, _ = crane
    gains = replace(Gains.from_spec(spec), kp=5.0, kd=3.0, mu=0.6)
    mlm, iterative = (make_controller(m, model, path, gains) for m in ("mlm", "iterative-3"))
    r_on, (r_off, _) = tracking_runs["mlm"], off_manifold_runs["iterative-3"]
    for r, instants in ((r_on, INSTANTS), (r_off, (0, 2, 5, 10))):
        for k in instants:
            T = terms(model, path, r.q[k], r.qd[k], r.t[k])
            u = mlm.compute(r.q[k], r.qd[k], r.t[k])
            qdd = constrained_acceleration(T, u, -T["gamma"])
            law = servo_law(T, gains)
            scale = np.abs(T["sigma_q"] @ qdd + T["gamma_s"]).max() + np.abs(law).max()
            np.testing.assert_allclose(T["sigma_q"] @ qdd + T["gamma_s"], law, rtol=0, atol=1e-9 * scale)
            iterative.compute(r.q[k], r.qd[k], r.t[k])
            law = constraint_law(T, gains)
            np.testing.assert_allclose(T["phi_q"] @ iterative.qdd + T["gamma"], law, rtol=0,
                                       atol=1e-9 * (np.abs(law).max() + np.abs(T["gamma"]).max()))
            if r is r_off:  # Ω/μ in place of Ωμ would be seen: (1/μ − μ)·2Ω φ̇ is far above the tolerance
                assert np.abs(2 * gains.omega * (1 / gains.mu - gains.mu) * T["phi_dot"]).max() > 1e4 * 1e-9 * (
                    np.abs(law).max() + np.abs(T["gamma"]).max())


def test_the_structured_terms_refuse_a_mass_matrix_that_depends_on_the_state():
    """The structured solver terms fold a constant M⁻¹ (natural coordinates give a constant M). A model whose M
    depended on q or on q̇ would be refused by name, not folded at one state."""
    from types import SimpleNamespace

    import casadi as ca

    from acroboter.codegen.solver_terms import constant_inverse_mass

    q, qd, s = ca.SX.sym("q", 2), ca.SX.sym("qd", 2), ca.SX.sym("s", 1)
    message = ("^the mass matrix depends on the state: natural coordinates give a constant one; the solver terms "
               "assume it$")
    for entry in (q[1], qd[0]):  # each of q and q̇ is looked at
        model = SimpleNamespace(inputs=[q, qd, s], mass_matrix=ca.diag(ca.vertcat(2.0 + entry**2, 3.0)))
        with pytest.raises(ValueError, match=message):
            constant_inverse_mass(model)
    constant = SimpleNamespace(inputs=[q, qd, s], mass_matrix=ca.SX(ca.DM([[2.0, 0.5], [0.5, 3.0]])))
    np.testing.assert_allclose(np.array(constant_inverse_mass(constant)) @ [[2.0, 0.5], [0.5, 3.0]], np.eye(2),
                               atol=1e-15)


def test_mlm_under_a_binding_limit_is_the_best_servo_fit_within_the_limits(crane, tracking_runs):
    """With the first winch's max 0.05 N below what it asks, MLM's input is the one within the limits whose
    servo accelerations come closest to the law: min |σ̈(u) − (−2k_D σ̇ − k_P² σ)| with σ̈(u) = σ_q q̈(u) + γ_s
    and q̈(u) from a dense solve of the constrained dynamics (numpy), by scipy's bounded least squares. At the
    recorded positions with q̇ twenty times the recorded one: the velocity terms (γ, γ_s, c) then weigh in the
    fit as much as the inputs do (on the slow path itself they are below the tolerance)."""
    from scipy.optimize import lsq_linear

    spec, model, path, _ = crane
    gains = Gains.from_spec(spec)
    lower, upper, preferred = (np.array(a, dtype=float) for a in spec.input_limits())
    r = tracking_runs["mlm"]
    for k in INSTANTS[1:4]:
        q, qd, t = r.q[k], 20.0 * r.qd[k], r.t[k]
        T = terms(model, path, q, qd, t)

        def servo_acceleration(u, T=T):  # T of this instant
            return T["sigma_q"] @ constrained_acceleration(T, u, -T["gamma"]) + T["gamma_s"]

        free = make_controller("mlm", model, path, gains).compute(q, qd, t).copy()
        tight = upper.copy()
        tight[0] = free[0] - 0.05
        u = make_controller("mlm", model, path, gains, limits=(lower, tight, preferred)).compute(q, qd, t).copy()
        base = servo_acceleration(np.zeros_like(u))
        E = np.column_stack([servo_acceleration(e) - base for e in np.eye(u.size)])
        best = lsq_linear(E, servo_law(T, gains) - base, bounds=(lower, tight), method="bvls", tol=1e-14,
                          max_iter=1000).x
        assert u[0] == pytest.approx(tight[0], abs=1e-9)
        np.testing.assert_allclose(u, best, rtol=0, atol=1e-7 * np.abs(best).max())
