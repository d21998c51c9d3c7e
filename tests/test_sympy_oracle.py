"""An independent sympy derivation of the model terms, compared with the compiled C.

The oracle below follows docs/model.md (§1-§5) directly and shares no code with
codegen/: only the spec parser and the index layout are reused. It derives M, c, φ, φ_q, φ̇, γ, σ, σ_q, σ̇,
γ_s, H and the energies of a spec in sympy, lambdifies them once per spec and compares them with the
generated C (shipped specs) or with the CasADi expressions (a variant spec that has no generated code)
at random states, to a norm-relative 1e-10.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import sympy as sp

from acroboter.model.layout import Layout, build_layout, nominal_coordinates
from acroboter.model.spec import (
    BodyThrust,
    BodyTorque,
    LevelTask,
    PositionTask,
    Spec,
    WinchTension,
    YawTask,
    load_spec,
    parse_spec,
)
from acroboter.runtime.cache import load_model

REPO = Path(__file__).resolve().parent.parent
SPEC_DIR = REPO / "model_spec"
SHIPPED = tuple(sorted(p.stem for p in SPEC_DIR.glob("*.toml")))
DESIGN_TOPOLOGY = ("acroboter", "lab_crane")  # the two-body, three-winch crane of the design file
RTOL = 1e-10
N_STATES = 6

# Terms of the oracle, and the generated function that returns each (besides model_terms).
TERMS = (
    "mass_matrix", "bias_forces", "phi", "phi_q", "phi_dot", "gamma",
    "sigma", "sigma_q", "sigma_dot", "gamma_s", "input_matrix",
)
ENERGY_TERMS = ("kinetic", "potential", "dissipated_power")
AXIS = {"u": 0, "v": 1, "w": 2}


# ------------------------------------------------------------------------------------------------
# The oracle: a direct transcription of the design file in sympy.
# ------------------------------------------------------------------------------------------------
def _kron_point(xi) -> sp.Matrix:
    """C(ξ) = [1, ξ1, ξ2, ξ3] ⊗ I3 (3 × 12)."""
    weights = sp.Matrix([[1, *[sp.Float(x) for x in xi]]])
    return sp.kronecker_product(weights, sp.eye(3))


def _dot(a: sp.Matrix, b: sp.Matrix):
    return (a.T * b)[0, 0]


def _jac(expr: sp.Matrix, syms) -> sp.Matrix:
    return expr.jacobian(sp.Matrix(syms))


@dataclass
class Oracle:
    spec: Spec
    layout: Layout
    exprs: dict[str, sp.Matrix]
    evaluate_all: object  # (q, qd, s, sd, sdd) -> list of arrays in the order of `names`
    names: tuple[str, ...]
    symbols: dict[str, tuple[sp.Symbol, ...]]  # q, qd, s, sd, sdd

    def evaluate(self, q, qd, s, sd, sdd) -> dict[str, np.ndarray]:
        values = self.evaluate_all(q, qd, s, sd, sdd)
        out = {}
        for name, v in zip(self.names, values, strict=True):
            v = np.array(v, dtype=float)
            out[name] = v.reshape(1) if v.ndim == 0 else (v[:, 0] if v.shape[1] == 1 else v)
        return out


def derive(spec: Spec) -> Oracle:
    """docs/model.md's terms of `spec`, derived here with SymPy, section by section."""
    sym = _Symbols(spec)
    T, U, D = _energies(spec, sym)
    q, qd, qdv = sym.q, sym.qd, sym.qdv
    dT_dqd = _jac(sp.Matrix([T]), qd).T
    M = _jac(dT_dqd, qd)
    c = _jac(dT_dqd, q) * qdv - _jac(sp.Matrix([T]), q).T + _jac(sp.Matrix([U]), q).T + _jac(sp.Matrix([D]), qd).T
    dissipated_power = (_jac(sp.Matrix([D]), qd) * qdv)[0, 0]
    phi = _geometric_constraints(spec, sym)
    phi_q, phi_dot, gamma = sym.time_derivatives(phi)
    sigma = _servo_constraints(spec, sym)
    sigma_q, sigma_dot, gamma_s = sym.time_derivatives(sigma)
    H = _input_matrix(spec, sym)
    exprs = {
        "mass_matrix": M, "bias_forces": c, "phi": phi, "phi_q": phi_q, "phi_dot": phi_dot, "gamma": gamma,
        "sigma": sigma, "sigma_q": sigma_q, "sigma_dot": sigma_dot, "gamma_s": gamma_s, "input_matrix": H,
        "kinetic": sp.Matrix([T]), "potential": sp.Matrix([U]), "dissipated_power": sp.Matrix([dissipated_power]),
    }
    names = tuple(exprs)
    args = [list(q), list(qd), list(sym.s), list(sym.sd), list(sym.sdd)]
    fn = sp.lambdify(args, [exprs[k] for k in names], "numpy", cse=True)
    return Oracle(spec, sym.lay, exprs, fn, names, {"q": q, "qd": qd, "s": sym.s, "sd": sym.sd, "sdd": sym.sdd})


class _Symbols:
    """The oracle's symbols: q, q̇, q̈ and the path signals s, ṡ, s̈, with the body blocks and points of q."""

    def __init__(self, spec: Spec):
        self.spec = spec
        self.lay = lay = build_layout(spec)
        n, ns = lay.n, lay.n_signals
        self.q = sp.symbols(f"q0:{n}", real=True)
        self.qd = sp.symbols(f"qd0:{n}", real=True)
        self.qdd = sp.symbols(f"qdd0:{n}", real=True)
        self.s = sp.symbols(f"s0:{ns}", real=True)
        self.sd = sp.symbols(f"sd0:{ns}", real=True)
        self.sdd = sp.symbols(f"sdd0:{ns}", real=True)
        self.qv, self.qdv = sp.Matrix(self.q), sp.Matrix(self.qd)

    def q_body(self, name: str, vec=None) -> sp.Matrix:
        i = self.lay.body_offset[name]
        return (self.qv if vec is None else vec)[i : i + 12, 0]

    def axis(self, name: str, a: str, vec=None) -> sp.Matrix:
        i = self.lay.body_offset[name] + 3 + 3 * AXIS[a]
        return (self.qv if vec is None else vec)[i : i + 3, 0]

    def world_point(self, end: str) -> sp.Matrix:
        if "." in end:
            body_name, point_name = end.split(".", 1)
            return _kron_point(self.spec.body(body_name).point(point_name)) * self.q_body(body_name)
        if end in self.lay.anchor_signal:
            j = self.lay.anchor_signal[end]
            return sp.Matrix(self.s[j : j + 3])
        return sp.Matrix([sp.Float(x) for x in self.spec.anchor(end).position])

    def time_derivatives(self, expr: sp.Matrix):
        """(J, ė, γ) by the chain rule (time enters only through s(t)), with ë = J q̈ + γ checked."""
        q, qd, qdd, s, sd, sdd = self.q, self.qd, self.qdd, self.s, self.sd, self.sdd
        jq = _jac(expr, q)
        expr_dot = jq * self.qdv + _jac(expr, s) * sp.Matrix(sd)
        expr_ddot = (
            _jac(expr_dot, q) * self.qdv + _jac(expr_dot, qd) * sp.Matrix(qdd)
            + _jac(expr_dot, s) * sp.Matrix(sd) + _jac(expr_dot, sd) * sp.Matrix(sdd)
        )
        # expr_ddot = J qdd + gamma: the qdd part must be J itself, gamma is the rest.
        assert (_jac(expr_ddot, qdd) - jq).expand() == sp.zeros(*jq.shape)
        gamma = expr_ddot.subs({x: 0 for x in qdd})
        return jq, expr_dot, gamma


def _energies(spec: Spec, sym: _Symbols):
    """§2: the kinetic energy (bodies, winch drums), the potential, the Rayleigh dissipation."""
    g = sp.Matrix([sp.Float(x) for x in spec.gravity])
    T, U, D = sp.Integer(0), sp.Integer(0), sp.Integer(0)
    for body in spec.bodies:
        i_g = sp.Matrix([[sp.Float(x) for x in row] for row in body.inertia])
        j_mat = sp.Rational(1, 2) * i_g.trace() * sp.eye(3) - i_g
        r, r_dot = sym.q_body(body.name)[0:3, 0], sym.q_body(body.name, sym.qdv)[0:3, 0]
        e_dot = [sym.axis(body.name, a, sym.qdv) for a in "uvw"]
        m = sp.Float(body.mass)
        T += sp.Rational(1, 2) * m * _dot(r_dot, r_dot)
        T += sp.Rational(1, 2) * sum(j_mat[a, b] * _dot(e_dot[a], e_dot[b]) for a in range(3) for b in range(3))
        U += -m * _dot(g, r)
        c_t, c_r = sp.Float(body.damping.translational), sp.Float(body.damping.rotational)
        D += sp.Rational(1, 2) * c_t * _dot(r_dot, r_dot) + sp.Rational(1, 4) * c_r * sum(_dot(e, e) for e in e_dot)
    for cable in spec.cables:
        if cable.winch is not None:
            speed = sym.qd[sym.lay.winch_index[cable.name]]
            T += sp.Rational(1, 2) * sp.Float(cable.winch.reflected_inertia) * speed**2
    return T, U, D


def _geometric_constraints(spec: Spec, sym: _Symbols) -> sp.Matrix:
    """§3: each body's axes orthonormal (w = u × v where asked), each cable |d|² − L²."""
    phi_rows = []
    for body in spec.bodies:
        u, v, w = (sym.axis(body.name, a) for a in "uvw")
        phi_rows += [_dot(u, u) - 1, _dot(v, v) - 1, _dot(w, w) - 1, _dot(u, v), _dot(v, w), _dot(w, u)]
        if body.redundant_constraints:
            phi_rows += list(w - u.cross(v))
    for cable in spec.cables:
        d = sym.world_point(cable.ends[0]) - sym.world_point(cable.ends[1])
        length = sym.q[sym.lay.winch_index[cable.name]] if cable.winch is not None else sp.Float(cable.length)
        phi_rows.append(_dot(d, d) - length**2)
    return sp.Matrix(phi_rows)


def _servo_constraints(spec: Spec, sym: _Symbols) -> sp.Matrix:
    """§5: the task's rows."""
    p, s = sym.lay.path_signal, sym.s
    sigma_rows = []
    for task in spec.task:
        if isinstance(task, PositionTask):
            sigma_rows += list(_kron_point(task.point) * sym.q_body(task.body) - sp.Matrix(s[p : p + 3]))
        elif isinstance(task, YawTask):
            a = sym.axis(task.body, task.axis)
            psi = s[p + 3] + (sp.pi / 2 if task.axis == "v" else 0)
            sigma_rows.append(-sp.sin(psi) * a[0] + sp.cos(psi) * a[1])
        elif isinstance(task, LevelTask):
            a = sym.axis(task.body, task.axis)
            sigma_rows += [a[0], a[1]]
        else:  # pragma: no cover - a new task kind needs an oracle row
            raise AssertionError(f"oracle does not know task {task}")
    return sp.Matrix(sigma_rows)


def _input_matrix(spec: Spec, sym: _Symbols) -> sp.Matrix:
    """§4: H(q), a column per actuator."""
    lay, columns = sym.lay, []
    for act in spec.actuators:
        col = sp.zeros(lay.n, 1)
        if isinstance(act, WinchTension):
            col[lay.winch_index[act.cable], 0] = -1
        elif isinstance(act, BodyTorque):
            i = lay.body_offset[act.body]
            a = sym.axis(act.body, act.axis)
            for k, e in enumerate(sym.axis(act.body, b) for b in "uvw"):
                col[i + 3 + 3 * k : i + 6 + 3 * k, 0] = sp.Rational(1, 2) * a.cross(e)
        elif isinstance(act, BodyThrust):
            i = lay.body_offset[act.body]
            col[i : i + 12, 0] = _kron_point(act.point).T * sym.axis(act.body, act.axis)
        else:  # pragma: no cover
            raise AssertionError(f"oracle does not know actuator {act}")
        columns.append(sp.nsimplify(act.gain) * col)
    return sp.Matrix.hstack(*columns)


# ------------------------------------------------------------------------------------------------
# Helpers
# ------------------------------------------------------------------------------------------------
def random_inputs(spec: Spec, lay: Layout, rng: np.random.Generator, noise: float = 0.05):
    """q near the spec's initial configuration, arbitrary velocities and signals."""
    q = nominal_coordinates(spec, lay) + noise * rng.standard_normal(lay.n)
    qd = rng.standard_normal(lay.n)
    s = np.zeros(lay.n_signals)
    for name, j in lay.anchor_signal.items():
        s[j : j + 3] = np.array(spec.anchor(name).position) + 0.2 * rng.standard_normal(3)
    p = lay.path_signal
    s[p : p + 3] = rng.uniform(-1, 1, 3)
    s[p + 3] = rng.uniform(-math.pi, math.pi)
    sd = rng.standard_normal(lay.n_signals)
    sdd = rng.standard_normal(lay.n_signals)
    return q, qd, s, sd, sdd


def assert_close(actual, expected, what: str, rtol: float = RTOL) -> None:
    """max|a - b| <= rtol * max(1, max|b|), with the worst element in the message."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != oracle's {expected.shape}"
    assert np.all(np.isfinite(actual)), f"{what}: non-finite values"
    if actual.size == 0:
        return
    err = np.abs(actual - expected)
    scale = max(1.0, float(np.abs(expected).max()))
    worst = np.unravel_index(int(np.argmax(err)), err.shape)
    assert err.max() <= rtol * scale, (
        f"{what}: max |diff| {err.max():.3e} > {rtol:g} * {scale:.3g} at {worst}: "
        f"got {actual[worst]!r}, oracle {expected[worst]!r}"
    )


def variant_spec() -> Spec:
    """acroboter.toml with the branches the shipped specs leave unused exercised."""
    data = tomllib.loads((SPEC_DIR / "acroboter.toml").read_text())
    data["name"] = "variant"
    cc, su = data["bodies"]
    su["redundant_constraints"] = True
    cc["redundant_constraints"] = True
    su["inertia"] = [[0.2, 0.01, -0.02], [0.01, 0.25, 0.03], [-0.02, 0.03, 0.35]]
    su["initial_yaw_deg"] = 30.0
    cc["damping"] = {"translational": 0.7, "rotational": 0.3}
    # A fixed anchor with a winch cable to the SU (anchor end without a signal, winch on an anchor).
    data["anchors"].append({"name": "hook", "position": [1.0, 0.5, 3.0]})
    data["cables"].append({"name": "stay", "ends": ["hook", "SU.b1"], "winch": {"reflected_inertia": 0.03}})
    for act in data["actuators"]:
        if act["name"] == "thrust_u":
            act["point"] = [0.1, -0.05, 0.2]
    data["actuators"] += [
        {"name": "tension_stay", "kind": "winch_tension", "cable": "stay"},
        {"name": "roll_torque", "kind": "body_torque", "body": "CC", "axis": "u"},
        {"name": "pitch_torque", "kind": "body_torque", "body": "SU", "axis": "v"},
        {"name": "thrust_w_cc", "kind": "body_thrust", "body": "CC", "axis": "w", "point": [0.0, 0.3, -0.1],
         "gain": -2.5},
    ]
    for task in data["task"]:
        if task["kind"] == "yaw":
            task["axis"] = "v"
        if task["kind"] == "position":
            task["point"] = [0.02, -0.01, -0.03]
    data["task"].append({"kind": "level", "body": "CC", "axis": "u"})
    return parse_spec(data, "<variant>")


_ORACLES: dict[str, Oracle] = {}


def oracle_for(name: str) -> Oracle:
    if name not in _ORACLES:
        spec = variant_spec() if name == "variant" else load_spec(SPEC_DIR / f"{name}.toml")
        _ORACLES[name] = derive(spec)
    return _ORACLES[name]


@pytest.fixture(scope="module", params=SHIPPED)
def shipped(request):
    oracle = oracle_for(request.param)
    return oracle, load_model(oracle.spec)


# ------------------------------------------------------------------------------------------------
# Compiled C (shipped specs) against the oracle
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", DESIGN_TOPOLOGY)
def test_layout_sizes_match_the_design(name):
    """The paper's n = 27, m = 16 and §4/§5's l = 6 inputs, 6 servo-constraints."""
    oracle = oracle_for(name)
    lay = oracle.layout
    assert (lay.n, lay.m, lay.l, lay.k) == (27, 16, 6, 6)
    assert oracle.exprs["phi"].shape == (lay.m, 1)
    assert oracle.exprs["sigma"].shape == (lay.k, 1)
    assert oracle.exprs["input_matrix"].shape == (lay.n, lay.l)


def test_each_compiled_function_matches_the_oracle(shipped):
    oracle, model = shipped
    rng = np.random.default_rng(20240611)
    for k in range(N_STATES):
        inputs = random_inputs(oracle.spec, oracle.layout, rng, noise=0.05 if k < 3 else 0.3)
        expected = oracle.evaluate(*inputs)
        for term in TERMS:
            assert_close(model.term(term, *inputs), expected[term], f"{oracle.spec.name} {term} (state {k})")
        energy = model.evaluate("energy", *inputs)
        for term in ENERGY_TERMS:
            assert_close(energy[term], expected[term], f"{oracle.spec.name} energy.{term} (state {k})")


def test_model_terms_matches_the_oracle(shipped):
    oracle, model = shipped
    rng = np.random.default_rng(7)
    for k in range(N_STATES):
        inputs = random_inputs(oracle.spec, oracle.layout, rng)
        expected = oracle.evaluate(*inputs)
        got = model.evaluate("model_terms", *inputs)
        assert set(got) == set(TERMS)
        for term in TERMS:
            assert_close(got[term], expected[term], f"{oracle.spec.name} model_terms.{term} (state {k})")


# ------------------------------------------------------------------------------------------------
# A variant spec without generated code: oracle against the CasADi expressions
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("parametric", [False, True])
def test_variant_spec_casadi_derivation_matches_the_oracle(parametric):
    """The variant (products of inertia, a yaw via v, a stay cable on a winch) against SymPy: the model with the
    spec's numbers folded in, and the plant's parametric model (every physical parameter a symbol, evaluated at
    the spec's values), whose inertia J = ½ tr(I_G) E − I_G is built apart (symbolic._axes_inertia)."""
    from acroboter.codegen.symbolic import build_symbolic_model
    from acroboter.model.physical import parameter_values

    oracle = oracle_for("variant")
    lay = oracle.layout
    # Sanity of the variant itself: the extra branches really are there.
    assert lay.m == 6 + 3 + 6 + 3 + 5
    assert any("yaw via v" in name for name in lay.servo_constraints)
    assert lay.l == 10 and lay.k == 8
    su = next(b for b in oracle.spec.bodies if b.name == "SU")
    assert su.inertia[0][1] != 0 and su.inertia[0][2] != 0 and su.inertia[1][2] != 0

    model = build_symbolic_model(oracle.spec, parametric=parametric)
    qd = model.inputs[1]
    exprs = [getattr(model, t) for t in TERMS]
    exprs += [model.kinetic, model.potential, ca.dot(qd, ca.gradient(model.dissipation, qd))]
    arguments = [*model.inputs, model.parameters] if parametric else model.inputs
    fn = ca.Function("variant_all", arguments, [ca.densify(ca.SX(e)) for e in exprs])
    theta = [ca.DM(parameter_values(oracle.spec))] if parametric else []
    rng = np.random.default_rng(99)
    for k in range(N_STATES):
        inputs = random_inputs(oracle.spec, lay, rng, noise=0.05 if k < 3 else 0.3)
        expected = oracle.evaluate(*inputs)
        got = fn.call([ca.DM(x) for x in inputs] + theta)
        for term, value in zip(TERMS + ENERGY_TERMS, got, strict=True):
            value = np.array(value.full(), dtype=float)
            value = value[:, 0] if value.shape[1] == 1 else value
            assert_close(value, expected[term], f"variant {term} (state {k})")


# ------------------------------------------------------------------------------------------------
# Structure the design file promises (§2), and the physics behind the natural-coordinate formulas
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", [*SHIPPED, "variant"])
def test_mass_matrix_constant_and_bias_affine(name):
    """§2: M is constant, c(q̇) is affine (gravity plus linear damping) and does not depend on q."""
    oracle = oracle_for(name)
    M, c = oracle.exprs["mass_matrix"], oracle.exprs["bias_forces"]
    assert not M.free_symbols
    assert M == M.T
    qd = oracle.symbols["qd"]
    assert c.free_symbols <= set(qd)
    assert _jac(c, qd).free_symbols == set()


def _rotation(rng: np.random.Generator) -> np.ndarray:
    a, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return a * np.sign(np.linalg.det(a))


def _evaluator(name: str):
    """(function name, q, qd, s, sd, sdd) -> outputs: the compiled C for a shipped spec, else CasADi's VM."""
    if name in SHIPPED:
        return load_model(oracle_for(name).spec).evaluate
    from acroboter.codegen.emit_c import GenerationContext

    functions = GenerationContext(oracle_for(name).spec).register_all().functions

    def evaluate(fname, *inputs):
        f = functions[fname]
        values = f.call([ca.DM(x) for x in inputs])
        return {
            f.name_out(i): np.array(v.full()).reshape(-1) if v.size2() == 1 else v.full() for i, v in enumerate(values)
        }

    return evaluate


@pytest.mark.parametrize("name", [*SHIPPED, "variant"])
def test_energies_and_input_powers_agree_with_rigid_body_physics(name):
    """At a consistent rigid motion (ė_i = ω × e_i) the natural-coordinate formulas must give
    T = ½ m|v|² + ½ Ω·I_G Ω (Ω = body-frame ω), the damping power c_t|v|² + c_r|ω|², and the input
    powers q̇ᵀ H = (a·ω for a torque about axis a, a·v_point for a thrust at ξ along a, −L̇ for a winch)."""
    oracle = oracle_for(name)
    spec, lay = oracle.spec, oracle.layout
    evaluate = _evaluator(name)
    rng = np.random.default_rng(3)
    for _ in range(4):
        q, _, s, sd, sdd = random_inputs(spec, lay, rng)
        qd = np.zeros(lay.n)
        kinetic, damping_power = 0.0, 0.0
        motion = {}
        for body in spec.bodies:
            i = lay.body_offset[body.name]
            rot = _rotation(rng)
            v, omega = rng.standard_normal(3), rng.standard_normal(3)
            q[i + 3 : i + 12] = rot.T.reshape(-1)
            qd[i : i + 3] = v
            qd[i + 3 : i + 12] = np.concatenate([np.cross(omega, rot[:, k]) for k in range(3)])
            omega_body = rot.T @ omega
            kinetic += 0.5 * body.mass * v @ v + 0.5 * omega_body @ np.array(body.inertia) @ omega_body
            damping_power += body.damping.translational * v @ v + body.damping.rotational * omega @ omega
            motion[body.name] = (rot, v, omega)
        for cable in spec.cables:
            if cable.winch is not None:
                j = lay.winch_index[cable.name]
                qd[j] = rng.standard_normal()
                kinetic += 0.5 * cable.winch.reflected_inertia * qd[j] ** 2
        energy = evaluate("energy", q, qd, s, sd, sdd)
        assert_close(energy["kinetic"], np.array([kinetic]), f"{name}: kinetic energy of a rigid motion")
        assert_close(energy["dissipated_power"], np.array([damping_power]), f"{name}: damping power of a rigid motion")

        H = evaluate("input_matrix", q, qd, s, sd, sdd)["input_matrix"]
        for col, act in enumerate(spec.actuators):
            if isinstance(act, WinchTension):
                expected = -qd[lay.winch_index[act.cable]]
            else:
                rot, v, omega = motion[act.body]
                a = rot[:, AXIS[act.axis]]
                if isinstance(act, BodyTorque):
                    expected = a @ omega
                else:
                    expected = a @ (v + np.cross(omega, rot @ np.array(act.point)))
            expected *= act.gain
            assert_close(np.array([qd @ H[:, col]]), np.array([expected]), f"{name}: power of input {act.name}")
