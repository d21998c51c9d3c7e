"""Shared fixtures: the shipped specs, their raw TOML dicts and their compiled models.

`crane` is parametrized over every shipped spec (model_spec/*.toml) and loads each CompiledModel
once per session. The model's input buffers are shared by every caller, so always go through
`Crane.term`, which sets all five inputs on every call (unspecified ones are zero / the rest
signals), never through `model.term` with only some inputs.
"""

from __future__ import annotations

import copy
import logging
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from acroboter.model.layout import Layout, nominal_coordinates
from acroboter.model.spec import Spec, load_spec
from acroboter.process.extras import install_line, missing
from acroboter.runtime.cache import load_model
from acroboter.runtime.compiled import CompiledModel

REPO = Path(__file__).resolve().parent.parent


def _models_from_the_generator() -> None:
    """ACROBOTER_TEST_MODELS=casadi: every model the tests load in this process is CasadiModel, the generator's
    functions evaluated by CasADi's VM (no C, no compiler), so a change to the generator (codegen/) acts at once.
    What `tools/mutation.py` sets to mutate the generator modules; slower (a VM call costs tens of µs, and every
    load builds the functions, about 2 s)."""
    import acroboter.runtime.cache as cache
    from acroboter.runtime.casadi_backend import CasadiModel

    def model(spec, source=None, root=None, build=True):
        # built anew on every load, never kept: a mutant switched on in a forked test process must reach it
        return CasadiModel(spec)

    cache.model_sources = lambda spec, root, generate=True: Path("<generator, in process>")
    cache.CompiledModel = model


if os.environ.get("ACROBOTER_TEST_MODELS") == "casadi":
    _models_from_the_generator()

# A test that needs an optional extra carries its marker (registered in pyproject.toml); without the extra it is
# skipped, and the reason (which extra, the pip line) shows in the summary (-ra). `make test` installs them all.
EXTRA_MARKERS = {"needs_mujoco": "mujoco", "needs_animation": "animation", "needs_dask": "dask"}


def missing_extra_reason(item) -> str | None:
    """Why `item` cannot run here: the first extra it is marked as needing that is not installed."""
    for marker, extra in EXTRA_MARKERS.items():
        if item.get_closest_marker(marker) is not None and (package := missing(extra)) is not None:
            return f"the {extra} extra is not installed ({package}): {install_line(extra)}"
    return None


def long_tests() -> dict[str, str]:
    """tests/long_tests.txt: node id (from the repository's root) -> what `make test` keeps in its place."""
    listed = {}
    for line in (REPO / "tests" / "long_tests.txt").read_text().splitlines():
        node, _, sample = line.partition("#")
        if node.strip():
            listed[node.strip()] = sample.strip()
    return listed


def pytest_collection_modifyitems(config, items):
    long = long_tests()
    for item in items:
        if (reason := missing_extra_reason(item)) is not None:
            item.add_marker(pytest.mark.skip(reason=reason))
        node = item.nodeid if item.nodeid.startswith("tests/") else f"tests/{item.nodeid}"
        if node in long or node.split("[")[0] in long:  # `make test` deselects them (-m "not long")
            item.add_marker(pytest.mark.long)


SPEC_DIR = REPO / "model_spec"
SHIPPED_SPECS = sorted(SPEC_DIR.glob("*.toml"))
SHIPPED_NAMES = [p.stem for p in SHIPPED_SPECS]


def numeric_environment() -> dict:
    """What decides the last bits of a run: the packages, and the CPU (numpy's BLAS and glibc's libm pick
    their kernels by vendor and SIMD features; an Intel machine and an AMD one differ by 1e-10 N in u).
    Golden digests apply only where this is the environment they were recorded in."""
    import platform

    import casadi
    import scipy

    vendor, flags = "", set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "vendor_id" and not vendor:
                vendor = value.strip()
            elif key.strip() == "flags" and not flags:
                flags = set(value.split())
    except OSError:
        vendor = platform.processor()
    simd = " ".join(f for f in ("avx2", "fma", "avx512f") if f in flags)
    return {"python": platform.python_version(), "machine": platform.machine(), "numpy": np.__version__,
            "scipy": scipy.__version__, "casadi": casadi.__version__, "cpu": f"{vendor} {simd}".strip()}


# The tests' short lift: the default crane's path one edge LIFT_HEIGHT_M straight up (no yaw turn), its winches held
# to [24, 29] N, where the load hangs on them at about 26.9 N: the statics leave the plan room, the ideal motion's
# peaks do not. Planned in seconds (tests/test_planning.py, test_output_folders, test_failed_runs, test_interrupts).
LIFT_HEIGHT_M = 0.1
LIFT_LIMITS_N = (24.0, 29.0)


def lift_spec_text(low: float = LIFT_LIMITS_N[0], high: float = LIFT_LIMITS_N[1], stops: tuple[float, ...] = ()) -> str:
    """The lift's spec text; `stops`: heights of corners on the way up (each edge then runs rest to rest)."""
    from acroboter.model.spec_edits import with_path, with_winch_limits

    text = with_winch_limits((SPEC_DIR / "acroboter.toml").read_text(), high, low)
    return with_path(text, [[0.0, 0.0, z] for z in (0.0, *stops, LIFT_HEIGHT_M)], yaw_deg=0.0)


def write_lift_spec(folder: Path, **edits) -> Path:
    """`lift_spec_text(**edits)` written to folder/lift.toml; its path."""
    path = Path(folder) / "lift.toml"
    path.write_text(lift_spec_text(**edits))
    return path


def raw_spec(name: str = "acroboter") -> dict:
    """A fresh (deep-copied) dict of a shipped spec's TOML, to mutate in a test."""
    return copy.deepcopy(_raw_cache(name))


_RAW: dict[str, dict] = {}


def _raw_cache(name: str) -> dict:
    if name not in _RAW:
        _RAW[name] = tomllib.loads((SPEC_DIR / f"{name}.toml").read_text())
    return _RAW[name]


@dataclass
class Crane:
    """A shipped spec with its compiled model and its nominal initial state."""

    path: Path
    spec: Spec
    model: CompiledModel
    q0: np.ndarray  # nominal initial coordinates (layout.nominal_coordinates)
    s0: np.ndarray  # signals at the start: anchors at their spec positions, targets at the tracked point, yaw 0

    @property
    def layout(self) -> Layout:
        return self.model.layout

    @property
    def name(self) -> str:
        return self.spec.name

    def term(self, name: str, q=None, qd=None, s=None, sd=None, sdd=None) -> np.ndarray:
        """One model term with every input set (q defaults to q0, s to s0, derivatives to 0)."""
        lay = self.layout
        zeros_q, zeros_s = np.zeros(lay.n), np.zeros(lay.n_signals)
        return self.model.term(
            name,
            q=self.q0 if q is None else q,
            qd=zeros_q if qd is None else qd,
            s=self.s0 if s is None else s,
            sd=zeros_s if sd is None else sd,
            sdd=zeros_s if sdd is None else sdd,
        )


def start_signals(spec: Spec, layout: Layout) -> np.ndarray:
    """s at t = 0: each moving anchor at its spec position, (x_d, y_d, z_d) at the initial tracked point, yaw_d = 0."""
    s = np.zeros(layout.n_signals)
    for anchor in spec.anchors:
        if anchor.name in layout.anchor_signal:
            j = layout.anchor_signal[anchor.name]
            s[j : j + 3] = anchor.position
    task = next(t for t in spec.task if t.kind == "position")
    body = spec.body(task.body)
    assert body.initial_yaw_deg == 0.0 and task.point == [0.0, 0.0, 0.0], "start_signals assumes a CoM task, no yaw"
    p = layout.path_signal
    s[p : p + 3] = body.initial_position
    s[p + 3] = 0.0
    return s


@pytest.fixture(autouse=True)
def _package_log_level():
    """A command run in-process with -v leaves the package logger at DEBUG (its console configures it per run);
    the next test in the same worker would see debug lines on stderr that a user without -v never sees."""
    logger = logging.getLogger("acroboter")
    level = logger.level
    yield
    logger.setLevel(level)


@pytest.fixture(autouse=True)
def _forget_static_needs():
    """The planner keeps the statics it solved along a path for the process (acroboter.planning.checks): a test that
    changes what they depend on (a solver's budget, say) must not see another test's answer."""
    yield
    from acroboter.planning.checks import clear_static_needs

    clear_static_needs()


@pytest.fixture(scope="session")
def compiled_cranes() -> dict[str, Crane]:
    """Every shipped spec's Crane, built once per session (lazily, see `crane`)."""
    return {}


@pytest.fixture(scope="session", params=SHIPPED_NAMES)
def crane(request, compiled_cranes) -> Crane:
    name = request.param
    if name not in compiled_cranes:
        path = SPEC_DIR / f"{name}.toml"
        spec = load_spec(path)
        model = load_model(spec)
        compiled_cranes[name] = Crane(
            path, spec, model, nominal_coordinates(spec, model.layout), start_signals(spec, model.layout)
        )
    return compiled_cranes[name]


def rigid_plant_rhs(model, path, u, zeta: float, omega: float):
    """An independent right-hand side of the bilateral Baumgarte DAE for scipy (a dense numpy KKT
    solve; every cable a rigid rod): x = [q, q̇] -> ẋ, with the input u held."""
    n = model.layout.n

    def rhs(t, x):
        q, qd = x[:n], x[n:]
        s, sd, sdd = path.signal_arrays(t)
        terms = model.evaluate("model_terms", q, qd, s, sd, sdd)
        m = terms["phi_q"].shape[0]
        kkt = np.block([[terms["mass_matrix"], terms["phi_q"].T], [terms["phi_q"], np.zeros((m, m))]])
        b = np.concatenate([
            terms["input_matrix"] @ u - terms["bias_forces"],
            -terms["gamma"] - 2 * zeta * omega * terms["phi_dot"] - omega**2 * terms["phi"],
        ])
        return np.concatenate([qd, np.linalg.solve(kkt, b)[:n]])

    return rhs


def build_in(root: Path, spec: Spec):
    """(spec, compiled model, desired path) of a test spec, generated and compiled under `root` (a
    temporary folder): test specs are not shipped, so neither their C nor their library is."""
    from acroboter.codegen.emit_c import generate
    from acroboter.sim.statics import desired_path

    generate(spec, root / "generated")
    model = load_model(spec, generated_dir=root / "generated", cache_dir=root / "build")
    return spec, model, desired_path(model)


def load_with_start(path: Path):
    """(spec, compiled model, desired path, static equilibrium at the start) of a spec file."""
    from acroboter.sim.statics import desired_path, solve_equilibrium

    spec = load_spec(path)
    model = load_model(spec)
    desired = desired_path(model)
    return spec, model, desired, solve_equilibrium(model, desired)
