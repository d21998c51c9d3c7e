"""The compiled C against CasADi's virtual machine, and the generator's determinism.

For each shipped spec the registered casadi.Functions of a fresh GenerationContext are evaluated at
random inputs and compared with the compiled library: both run the same expression graph, so they
must agree to the last few bits (norm-relative 1e-12). Generating a spec twice must give the same bytes.
"""

from __future__ import annotations

import os
import subprocess
import sys
import zlib
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from acroboter.codegen.emit_c import FUNCTIONS, GenerationContext
from acroboter.model.layout import nominal_coordinates
from acroboter.model.spec import load_spec
from acroboter.runtime.cache import load_model

REPO = Path(__file__).resolve().parent.parent
SPEC_DIR = REPO / "model_spec"
SHIPPED = sorted(p.stem for p in SPEC_DIR.glob("*.toml"))
RTOL = 1e-12
N_STATES = 5


class Pair:
    """A spec's fresh GenerationContext and its compiled model."""

    def __init__(self, name: str):
        self.spec = load_spec(SPEC_DIR / f"{name}.toml")
        self.ctx = GenerationContext(self.spec).register_all()
        self.model = load_model(self.spec)
        self.layout = self.model.layout


@pytest.fixture(scope="module", params=SHIPPED)
def pair(request) -> Pair:
    return Pair(request.param)


def random_model_inputs(pair: Pair, rng: np.random.Generator, noise: float) -> dict[str, np.ndarray]:
    """q near the initial configuration, arbitrary velocities and signals (s, ṡ, s̈)."""
    lay = pair.layout
    q = nominal_coordinates(pair.spec, lay) + noise * rng.standard_normal(lay.n)
    s = rng.standard_normal(lay.n_signals)
    for name, j in lay.anchor_signal.items():
        s[j : j + 3] = np.array(pair.spec.anchor(name).position) + 0.1 * rng.standard_normal(3)
    s[lay.path_signal + 3] = rng.uniform(-np.pi, np.pi)
    return {
        "q": q,
        "qd": rng.standard_normal(lay.n),
        "s": s,
        "sd": rng.standard_normal(lay.n_signals),
        "sdd": rng.standard_normal(lay.n_signals),
    }


def random_extra_input(pair: Pair, name: str, size: int, model_inputs, rng: np.random.Generator) -> np.ndarray:
    """Inputs of the solver-shaped functions (beyond q, qd, s, sd, sdd), in a physical range."""
    if name == "p":  # k_P, k_D, α̃, α̂, Ω, μ, k_I, then the integral z of each servo-constraint
        gains = np.array([5.0, 5.0, 1e7, 1e7, 10.0, 1.0, 20.0]) * rng.uniform(0.5, 2.0, 7)
        return np.concatenate([gains, 1e-2 * rng.standard_normal(size - gains.size)])
    if name == "x":  # plant state [q, q̇, work of inputs, work of anchors, damping energy]
        return np.concatenate([model_inputs["q"], model_inputs["qd"], rng.standard_normal(size - 2 * pair.layout.n)])
    if name == "u":
        return 30.0 * rng.standard_normal(size)
    if name == "settings":  # h, ζ_B, ω_B
        return np.array([0.002, 1.0, 20.0]) * rng.uniform(0.5, 2.0, size)
    if name == "stage_signals":  # [s, ṡ, s̈] at t, t + h/2, t + h
        sig = np.concatenate([model_inputs[k] for k in ("s", "sd", "sdd")])
        return np.concatenate([sig + 1e-3 * k * rng.standard_normal(sig.size) for k in range(3)])
    if name == "cable_active":  # the plant's cable mask: 1 taut, 0 slack
        return rng.integers(0, 2, size).astype(float)
    if name == "chol":  # LAPACK potrf's upper factor of an SPD matrix (the lower triangle is not read)
        n = pair.layout.n
        a = rng.standard_normal((n, n))
        return np.linalg.cholesky(a @ a.T + n * np.eye(n)).T.reshape(-1, order="F") + np.tril(
            rng.standard_normal((n, n)), -1).reshape(-1, order="F")
    if name in ("force", "qdd", "qdd_sum"):
        return rng.standard_normal(size)
    if name == "plant_params":  # physical parameters (acroboter.model.physical): the spec's ±2 % (inertias physical)
        from acroboter.model.physical import parameter_values

        return parameter_values(pair.spec) * rng.uniform(0.98, 1.02, size)
    if name == "no_plant_params" and size == 0:  # the folded plant's empty parameter input
        return np.zeros(0)
    raise AssertionError(f"no random value for input '{name}' of size {size}: teach this test about it")


def evaluate_casadi(f: ca.Function, values: list[np.ndarray]) -> dict[str, np.ndarray]:
    # Buffers are flat (column-major); casadi wants each input in its own shape.
    out = f.call([ca.reshape(ca.DM(v), *f.size_in(i)) for i, v in enumerate(values)])
    return {
        f.name_out(i): (np.array(v.full()).reshape(-1) if v.size2() == 1 else np.array(v.full()))
        for i, v in enumerate(out)
    }


def assert_close(actual, expected, what: str, rtol: float = RTOL) -> None:
    """max|a − b| <= rtol · max(1, max|b|), with the worst element in the message."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: compiled shape {actual.shape} != CasADi's {expected.shape}"
    assert np.all(np.isfinite(expected)), f"{what}: CasADi gives non-finite values (bad test input)"
    err = np.abs(actual - expected)
    if err.size == 0:
        return
    scale = max(1.0, float(np.abs(expected).max()))
    worst = np.unravel_index(int(np.argmax(err)), err.shape)
    assert err.max() <= rtol * scale, (
        f"{what}: max |diff| {err.max():.3e} > {rtol:g} * {scale:.3g} at {worst}: "
        f"compiled {actual[worst]!r}, CasADi {expected[worst]!r}"
    )


def test_compiled_library_has_every_registered_function(pair):
    ctx, model = pair.ctx, pair.model
    assert set(FUNCTIONS) <= set(ctx.functions)
    assert set(model.functions) == set(ctx.functions)
    for name, f in ctx.functions.items():
        assert model.manifest["functions"][name]["symbol"] == f.name()
        assert list(model.functions[name].outputs) == [f.name_out(i) for i in range(f.n_out())], name


@pytest.mark.parametrize("fname", list(FUNCTIONS))
def test_model_function_matches_casadi(pair, fname):
    """The functions of FUNCTIONS take (q, qd, s, sd, sdd): compare through CompiledModel.evaluate."""
    f = pair.ctx.functions[fname]
    assert [f.name_in(i) for i in range(f.n_in())] == ["q", "qd", "s", "sd", "sdd"]
    rng = np.random.default_rng(zlib.crc32(f"{pair.spec.name}/{fname}".encode()))
    for k in range(N_STATES):
        inputs = random_model_inputs(pair, rng, noise=0.02 if k < 2 else 0.3)
        expected = evaluate_casadi(f, list(inputs.values()))
        got = pair.model.evaluate(fname, **inputs)
        assert set(got) == set(expected)
        for out, value in expected.items():
            assert_close(got[out], value, f"{pair.spec.name}_{fname}.{out} (state {k})")


def test_solver_functions_match_casadi(pair):
    """Functions registered besides FUNCTIONS (solver terms, plant step) take other inputs too:
    write each input into the compiled model's buffer of that name, call, compare."""
    extra = [name for name in pair.ctx.functions if name not in FUNCTIONS]
    if not extra:
        pytest.skip("only the model functions are registered")
    rng = np.random.default_rng(777)
    for k in range(N_STATES):
        model_inputs = random_model_inputs(pair, rng, noise=0.02 if k < 2 else 0.1)
        for fname in extra:
            f = pair.ctx.functions[fname]
            values = []
            for i in range(f.n_in()):
                name = f.name_in(i)
                v = model_inputs.get(name)
                values.append(v if v is not None else random_extra_input(pair, name, f.numel_in(i), model_inputs, rng))
            expected = evaluate_casadi(f, values)
            bound = pair.model.functions[fname]
            assert len(bound.inputs) == len(values)
            for buf, v in zip(bound.inputs, values, strict=True):
                buf[:] = v
            bound.call()
            for out, value in expected.items():
                assert_close(bound.outputs[out], value, f"{pair.spec.name}_{fname}.{out} (state {k})")


# --- determinism -----------------------------------------------------------------------------------------------
def _tree(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _assert_same_tree(a: dict[str, bytes], b: dict[str, bytes], what: str) -> None:
    assert sorted(a) == sorted(b), f"{what}: different file sets"
    differ = [name for name in a if a[name] != b[name]]
    assert not differ, f"{what}: files differ: {differ}"


@pytest.mark.parametrize("name", SHIPPED)
def test_generation_is_deterministic(name, tmp_path):
    spec = load_spec(SPEC_DIR / f"{name}.toml")
    first, second = tmp_path / "first", tmp_path / "second"
    GenerationContext(spec).register_all().write(first)
    GenerationContext(spec).register_all().write(second)
    a, b = _tree(first), _tree(second)
    assert any(n.endswith(".c") for n in a) and "manifest.json" in a
    _assert_same_tree(a, b, f"{name} generated twice in one process")

    # Another process with another hash seed: no set or dict order may leak into the output.
    third = tmp_path / "third"
    script = (
        "import sys; from pathlib import Path; from acroboter.model.spec import load_spec; "
        "from acroboter.codegen.emit_c import GenerationContext; "
        "GenerationContext(load_spec(sys.argv[1])).register_all().write(Path(sys.argv[2]))"
    )
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    result = subprocess.run(
        [sys.executable, "-c", script, str(SPEC_DIR / f"{name}.toml"), str(third)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr
    _assert_same_tree(a, _tree(third), f"{name} generated in another process")
