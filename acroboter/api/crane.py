"""The library's face: a crane from its spec, its controllers, and closed-loop simulations.

    import acroboter

    crane = acroboter.Crane.from_toml(acroboter.example_spec("acroboter"))   # validate, compile once, bind
    start = crane.equilibrium()                     # static start: q, multipliers, inputs
    controller = crane.controller("penalty")        # for a plant of your own: u = controller.step(q, qd, t)
    result = crane.simulate("iterative", iterations=5, duration=20.0, kd=6.0)   # -> acroboter.Result

Methods are "mlm", "penalty", "iterative" (with `iterations=N`, default the spec's first count) or
"iterative-N". Keyword overrides replace the spec's controller settings for that call: kp, kd,
alpha_geometric, alpha_servo, omega, mu, recovery, kappa, ki (integral action, docs/integral_action.md),
saturation ("qp" or "underactuation": how a limit is met, docs/saturation.md).
A `trajectory` (a SampledTrajectory, or a function t -> (position, velocity, acceleration) with
`duration`) replaces the spec's waypoints.
"""

from __future__ import annotations

import logging
import math
import numbers
import threading
from collections.abc import Callable, Mapping
from os import PathLike
from pathlib import Path

import numpy as np

from ..control.controllers import make_controller
from ..control.path import DesiredPath, SampledTrajectory, TrajectoryPath
from ..model.physical import parameter_names, parameter_values
from ..model.plausibility import plausibility_warnings
from ..model.ranges import delay_problem
from ..model.settings import Gains, resolve_gains
from ..model.spec import (
    MAX_CONTROL_STEPS,
    MAX_ITERATIONS,
    Spec,
    SpecError,
    load_spec,
)
from ..process.locations import example_spec
from ..runtime.cache import load_model
from ..runtime.compiled import CompiledModel
from ..sim.fast_estimator import make_estimator
from ..sim.feasibility import Feasibility, check_path
from ..sim.open_loop import held_path, simulate_open_loop
from ..sim.records import Scenario
from ..sim.result import Result
from ..sim.sensing import check_measurable
from ..sim.sensing import resolve as resolve_sensing
from ..sim.simulation import setup_default, simulate
from ..sim.statics import Equilibrium, desired_path, inputs_outside_limits, solve_equilibrium, start_targets
from .dynamics import evaluate

# Untimed control steps at the start state before a timed run: the first calls page code and data in.
WARM_UP_STEPS = 200

Trajectory = SampledTrajectory | Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


class Crane:
    """A crane model: its validated spec, the compiled dynamics bound once, its desired path.

    Names, as the generated code orders them: `coordinates` (natural coordinates, e.g. "SU.r_x"),
    `inputs` (actuators, e.g. "tension_1") with `input_units`, `servo_constraints` (the task),
    `cables`."""

    def __init__(self, spec: Spec, model: CompiledModel, source: Path | None = None):
        self.spec, self.model, self.source = spec, model, source
        self.layout = model.layout
        self.name: str = spec.name
        self.coordinates: list[str] = list(self.layout.coordinates)
        self.inputs: list[str] = list(self.layout.inputs)
        self.input_units: list[str] = list(self.layout.input_units)
        self.servo_constraints: list[str] = list(self.layout.servo_constraints)
        self.cables: list[str] = [c.name for c in spec.cables]
        self.scenario = Scenario.from_model(model)
        self._path: DesiredPath | None = None
        self._start: Equilibrium | None = None
        # Numbers each valid but implausible together (a mass in grams, ...): said once, here, and kept.
        self.warnings: list[str] = [f"{field}: {why}" for field, why in plausibility_warnings(spec)]
        for warning in self.warnings:
            logging.getLogger("acroboter").warning("spec '%s': %s", spec.name, warning)
        if spec.sensing is not None:  # a [sensing] that measures too little is refused here (SpecError)
            check_measurable(model, spec.sensing, source=str(source or spec.name))

    # --- construction -----------------------------------------------------------------------------
    @classmethod
    def from_toml(cls, path: str | PathLike, cache_dir: str | PathLike | None = None) -> Crane:
        """Load and validate a spec file, generate and compile its model on first use (into the cache:
        `cache_dir`, else $ACROBOTER_CACHE_DIR, else the per-user cache), and bind it."""
        spec = load_spec(Path(path))
        return cls(spec, load_model(spec, cache_dir=None if cache_dir is None else Path(cache_dir)), Path(path))

    @classmethod
    def from_example(cls, name: str = "acroboter", cache_dir: str | PathLike | None = None) -> Crane:
        """One of the shipped cranes by name (acroboter.example_names())."""
        return cls.from_toml(example_spec(name), cache_dir)

    @classmethod
    def from_spec(cls, spec: Spec, cache_dir: str | PathLike | None = None) -> Crane:
        return cls(spec, load_model(spec, cache_dir=None if cache_dir is None else Path(cache_dir)))

    def __repr__(self) -> str:
        return (f"<Crane {self.name}: {len(self.coordinates)} coordinates, {len(self.inputs)} inputs, "
                f"{len(self.servo_constraints)} servo-constraints, {len(self.cables)} cables>")

    # --- the pieces -------------------------------------------------------------------------------
    @property
    def path(self) -> DesiredPath:
        """The spec's desired path (waypoints, mean speed, yaw turn)."""
        if self._path is None:
            self._path = desired_path(self.model.data())
        return self._path

    def input_limits(self) -> dict[str, tuple[float, float, float]]:
        """Per input: (min, max, preferred), as the spec resolves them."""
        lower, upper, preferred = self.spec.input_limits()
        return {name: (float(lo), float(hi), float(p))
                for name, lo, hi, p in zip(self.inputs, lower, upper, preferred, strict=True)}

    def desired(self, trajectory: Trajectory | None = None, duration: float | None = None) -> DesiredPath:
        """The path a controller follows: the spec's, or the given trajectory's."""
        if trajectory is None:
            return self.path
        if isinstance(trajectory, SampledTrajectory):
            duration = trajectory.duration if duration is None else duration
        elif not callable(trajectory):
            raise TypeError("trajectory: expected a SampledTrajectory or a function t -> (position, velocity, "
                            "acceleration)")
        if duration is None:
            raise ValueError("a trajectory function needs its duration: pass duration=seconds")
        _, start_yaw = start_targets(self.model.data())
        return TrajectoryPath(self.spec, self.layout, trajectory, float(duration), start_yaw)

    def equilibrium(self, trajectory: Trajectory | None = None, duration: float | None = None) -> Equilibrium:
        """The static equilibrium at the start of the path: q, constraint multipliers, inputs (at rest)."""
        if trajectory is None:
            if self._start is None:
                self._start = solve_equilibrium(self.model.data(), self.path)
            return self._start
        return solve_equilibrium(self.model.data(), self.desired(trajectory, duration))

    # --- the dynamics terms at a state (acroboter.api.dynamics; docs/model.md §1-5) ---------------------
    def _working(self):
        """This thread's working copy of the model for the dynamics terms (made once per thread)."""
        local = self.__dict__.setdefault("_threads", threading.local())
        if not hasattr(local, "data"):
            local.data = self.model.data()
        return local.data

    def mass_matrix(self, q) -> np.ndarray:
        """M(q), (n, n): kg on the bodies' centres, kg·m² on their axes, the drums' reflected inertia (kg)
        on the winch lengths (constant in natural coordinates)."""
        return evaluate(self._working(), self.path, "mass_matrix", q)

    def bias_forces(self, q, qd, t: float = 0.0) -> np.ndarray:
        """c(q, q̇, t), (n,): every generalized force but the inputs' and the constraints' (gravity,
        damping, the velocity terms), on the left: M q̈ + c = H u − φ_qᵀ λ. N (N·m on the axes' rows)."""
        return evaluate(self._working(), self.path, "bias_forces", q, qd, t)

    def input_matrix(self, q) -> np.ndarray:
        """H(q), (n, l): the generalized force of each input per unit (`crane.inputs`, their units)."""
        return evaluate(self._working(), self.path, "input_matrix", q)

    def constraints(self, q, t: float = 0.0) -> np.ndarray:
        """φ(q, t), (m,): the geometric constraints (`crane.layout.constraints`): the bodies' axes
        orthonormal (unitless) and each cable |p_a − p_b|² − L² (m²; ≤ 0 for a slack cable), the moving
        anchors where the path has them at t. 0 on a consistent configuration."""
        return evaluate(self._working(), self.path, "constraints", q, t=t)

    def constraint_jacobian(self, q, t: float = 0.0) -> np.ndarray:
        """φ_q(q, t) = ∂φ/∂q, (m, n)."""
        return evaluate(self._working(), self.path, "constraint_jacobian", q, t=t)

    def servo_error(self, q, t: float = 0.0) -> np.ndarray:
        """σ(q, t), (k,): the servo-constraints' values (named in `crane.servo_constraints`) against the
        spec's desired path at t: the tracked point's position error (m), yaw and level (unitless). 0 on
        the path."""
        return evaluate(self._working(), self.path, "servo_error", q, t=t)

    def servo_jacobian(self, q, t: float = 0.0) -> np.ndarray:
        """σ_q(q, t) = ∂σ/∂q, (k, n)."""
        return evaluate(self._working(), self.path, "servo_jacobian", q, t=t)

    def mjcf(self, timestep: float | None = None, plant_params: Mapping[str, float] | None = None,
             pose: str = "spec") -> str:
        """The crane's MJCF model for MuJoCo (docs/mujoco.md): mujoco.MjModel.from_xml_string(crane.mjcf());
        `plant_params` as in simulate(), `timestep` MuJoCo's step (default 1e-4 s); pose="static": the
        reference pose is the static equilibrium, with a keyframe `static_start` of the inputs holding it
        (pose="spec": the spec's initial configuration, the XML of generated/)."""
        from ..model.mjcf_model import DEFAULT_TIMESTEP, mjcf_xml
        from ..model.physical import with_parameters

        if pose not in ("spec", "static"):
            raise ValueError(f"pose: expected 'spec' or 'static', found {pose!r}")
        spec = with_parameters(self.spec, plant_params or {})
        start = None
        if pose == "static":
            equilibrium = self.equilibrium()
            start = (equilibrium.q, equilibrium.inputs)
            for problem in inputs_outside_limits(self.spec, self.layout, equilibrium.inputs):  # MuJoCo clamps ctrl
                logging.getLogger("acroboter").warning(
                    "spec '%s': the static start is outside the input limits: %s; the keyframe static_start's ctrl "
                    "is outside ctrlrange, which MuJoCo clamps", self.spec.name, problem)
        return mjcf_xml(spec, DEFAULT_TIMESTEP if timestep is None else timestep, start)

    def plant_parameters(self) -> dict[str, float]:
        """The physical parameters a plant may differ in (`simulate(plant_params=...)`), with the spec's
        values: gravity.x/y/z, <body>.mass, <body>.inertia.xx …, <body>.damping.translational/rotational,
        <body>.points.<point>.x/y/z, <cable>.length, <cable>.winch.reflected_inertia (acroboter.model.physical)."""
        return dict(zip(parameter_names(self.spec), map(float, parameter_values(self.spec)), strict=True))

    def gains(self, **overrides) -> Gains:
        """The spec's controller settings with `overrides` checked and applied: the names of
        acroboter.model.controller_parameters.OVERRIDES (kp, kd, alpha_geometric, alpha_servo, omega, mu, ki,
        recovery, kappa, saturation), each in its declared range; kp, kd stable sampled at the spec's rate; ki ≥ 0
        below 2·kd·kp² (docs/integral_action.md). A bad value is a GainError (a ValueError) naming the parameter."""
        return resolve_gains(self.spec, **overrides)

    def sensing(self, sensing=None):
        """The sensing a run uses (acroboter.model.schema.Sensing, or None: the plant's state): None, the spec's
        section; False, none; a mapping of overrides onto the spec's section (or, without one, the
        groups 'positions', 'axes', 'lengths' measuring every coordinate exactly): `noise` and
        `quantization` ({group: value}), `delay_periods`, `seed`, `velocity_filter_s`,
        `projection_iterations`, `groups`, and the sample checks' `max_speed`, `max_axis_rate`, `max_coast_periods`
        (docs/sensing.md, "Bad samples"). A bad value, or groups that measure too little for the
        constraints to determine the rest, is a SpecError naming the field (docs/sensing.md)."""
        chosen = resolve_sensing(self.spec, sensing, source=str(self.source or self.name))
        if chosen is not None and chosen is not self.spec.sensing:
            check_measurable(self.model.data(), chosen, source=str(self.source or self.name))
        return chosen

    def check_delay(self, sensing, duration: float) -> None:
        """A SpecError unless the sensing's delay is shorter than a run of `duration` seconds."""
        if sensing is not None and (problem := delay_problem(sensing.delay_periods, self.spec.controller.rate_hz,
                                                             duration)) is not None:
            raise SpecError(str(self.source or self.name), [("sensing.delay_periods", problem)])

    def method_name(self, method: str, iterations: int | None = None) -> str:
        """'mlm', 'penalty', 'iterative-N'; 'iterative' takes `iterations` (default the spec's first)."""
        if method == "iterative":
            iterations = self.spec.controller.penalty.iterations[0] if iterations is None else iterations
            whole = isinstance(iterations, numbers.Integral) and not isinstance(iterations, bool)
            if not whole or not 1 <= iterations <= MAX_ITERATIONS:
                raise ValueError(f"iterations: expected a whole number from 1 to {MAX_ITERATIONS}, "
                                 f"found {iterations!r}")
            return f"iterative-{int(iterations)}"
        if iterations is not None:
            raise ValueError(f"iterations= goes with method 'iterative', not '{method}'")
        count = method.removeprefix("iterative-")
        if method in ("mlm", "penalty") or (method.startswith("iterative-") and count.isascii() and count.isdigit()
                                            and 1 <= int(count) <= MAX_ITERATIONS):
            return method
        raise ValueError(f"unknown method '{method}': use mlm, penalty, iterative or iterative-N "
                         f"(1 <= N <= {MAX_ITERATIONS})")

    def controller(self, method: str = "penalty", trajectory: Trajectory | None = None,
                   duration: float | None = None, iterations: int | None = None, fast: bool = False,
                   **overrides) -> Controller:
        """A controller for a plant of your own: `u = controller.step(q, qd, t)` (`fast`: as in `simulate`)."""
        if not isinstance(fast, bool):
            raise ValueError(f"fast: expected True or False, found {fast!r}")
        name = self.method_name(method, iterations)
        path = self.desired(trajectory, duration)
        return Controller(make_controller(name, self.model.data(), path, self.gains(**overrides), fast=fast),
                          self.inputs)

    def stateful_controller(self, method: str = "penalty", sensing=None, iterations: int | None = None,
                            fast: bool = False, **overrides):
        """The exported C controller's step in Python (acroboter.sim.stateful_controller.StatefulController):
        `init(q0)`, `code = step(y, t)` with the command in `.u`, `reset()`, `reinit()`; replays a run's
        `result.measurements` as the C would (docs/controller.md). `sensing` as in `simulate` (none: y = [q; q̇])."""
        from .stateful import stateful_controller

        return stateful_controller(self, method, sensing, iterations, fast, overrides)

    def export_controller(self, method: str = "penalty", out: str | PathLike = "build/embedded", sensing=None,
                          mlm_system: str = "reduced", penalty_system: str = "auto", **overrides) -> list[Path]:
        """Write the stateful C controller (`acroboter export-step --stateful`) into `out`: its four files."""
        from .stateful import export_controller

        return export_controller(self, method, out, sensing, mlm_system, penalty_system, overrides)

    def check_path(self, duration: float | None = None, trajectory: Trajectory | None = None,
                   **overrides) -> Feasibility:
        """Before a run: can the ideal motion be realised within the input limits (MLM on the plant)?"""
        path = self.desired(trajectory, duration)
        duration = _duration(path, duration)
        start = self.equilibrium(trajectory, duration)
        data = self.model.data()
        return check_path(data, path, setup_default(data, path), start.q, duration,
                          self.gains(**overrides))

    def plan(self, margin: float = 0.05, max_speed: float | None = None, max_accel: float | None = None,
             trajectory: Trajectory | None = None, duration: float | None = None, intervals: int = 120,
             certify: bool = True, verbose: bool = False, window: int | None = None, corners: str = "rest",
             max_jerk: float | None = None, tolerance: float | None = None, shaper: str | None = None):
        """The fastest timing of the path's geometry (the spec's waypoints, or `trajectory`'s) whose ideal motion
        keeps every input within its limits less `margin` (a fraction of each limit span, docs/planning.md),
        optionally with the tracked point's speed ≤ `max_speed` (m/s), acceleration ≤ `max_accel` (m/s²) and jerk
        ≤ `max_jerk` (m/s³: a smooth timing); with `tolerance` (m) the fastest smooth one whose flights by every
        `certify` method stay within that position error. Returns a Plan: `plan.trajectory` for
        `simulate(trajectory=...)`, `plan.to_csv(path)` for `acroboter run --trajectory FILE`, `plan.summary()`.
        A need at rest beyond the limits anywhere on the path (no timing can help) is a StaticLimitError naming
        the place and the input; a plan that is not the one asked for a PlanFailure holding it (`err.plan`; its
        subclass CertificateError for a failed certificate); other failures a PlanningError (all ValueErrors).
        `certify`: True flies the plan with MLM at the spec's rate on the own plant, the limits applied; a method
        name or a list of them ("penalty", "iterative-3") flies it with each; False skips it.
        `corners` on a waypoint path: "rest" (default), every edge from rest to rest with the swing included, the
        edges solved one by one; "swing", the swing carried over the corners, `window` phases optimised together in
        a receding window (default 2; 0: the whole path in one solve, slow on long paths; docs/planning.md).
        `shaper` ("zv", "zvd", "unshaped"): no optimiser, the path's own timing input-shaped edge by edge."""
        from ..planning.planner import check_plannable
        from ..planning.tolerance import check_plan_options, plan_path

        options = {"margin": margin, "max_speed": max_speed, "max_accel": max_accel, "max_jerk": max_jerk,
                   "intervals": intervals, "verbose": verbose, "window": window, "corners": corners, "shaper": shaper}
        check_plan_options(options, tolerance, certify)
        if not isinstance(certify, bool):  # method names: each flies the plan in the certificate
            certify = self._certified(certify)
        path = self.desired(trajectory, duration)
        check_plannable(path, self.spec.controller.rate_hz)  # before any work: a bounded problem, a path that moves
        start = self.equilibrium(trajectory, duration)
        return plan_path(self.model.data(), path, start.q, certify, tolerance, **options)

    def _certified(self, methods) -> tuple[str, ...]:
        """The certificate's methods, each checked as `method_name` checks it (a PlanningError before any work)."""
        from ..planning.ideal_motion import PlanningError

        names = (methods,) if isinstance(methods, str) else tuple(methods)
        if not names:
            raise PlanningError("certify: no method given; give False to skip the certificate")
        try:
            return tuple(self.method_name(name) for name in names)
        except ValueError as err:
            raise PlanningError(f"certify: expected True, False or methods (mlm, penalty, iterative-N): {err}") \
                from None

    def simulate(self, method: str = "penalty", duration: float | None = None,
                 trajectory: Trajectory | None = None, iterations: int | None = None,
                 warm_up: int = WARM_UP_STEPS, progress: Callable[[int], object] | None = None,
                 plant_params: Mapping[str, float] | None = None, sensing=None, plant: str = "own",
                 mujoco_timestep: float | None = None, fast: bool = False, **overrides) -> Result:
        """Closed loop from the static start: the controller at the spec's rate, the plant's RK4 between.

        `plant`: "own" (the project's Baumgarte RK4 plant) or "mujoco" (MuJoCo on the spec's MJCF
        model, docs/mujoco.md, at `mujoco_timestep` seconds, default 1e-4; the controller still runs
        at the spec's rate with the input held in between).

        `plant_params` (name -> value, e.g. {"SU.mass": 8.8}; the names: `plant_parameters()`) make the
        plant's crane differ from the controller's model, which keeps the spec's numbers; checked
        before any work (an unknown name or a value the spec would refuse: PlantParameterError, a
        ValueError). The run starts at the model's static equilibrium.

        `duration` defaults to the path's. A run that diverges (state or input not finite, the tracked
        point more than 0.5 m off, no consistent cable state) stops there and says so
        (`result.diverged_at`); a method that cannot handle the crane at all raises
        SingularSystemError (e.g. MLM with redundant constraints). `progress(n)` is called every
        control step (e.g. a tqdm bar's update).

        `sensing`: what the controller measures instead of reading the plant's state (docs/sensing.md):
        None, the spec's [sensing] section (none without one); False, none; a mapping of overrides
        ({"noise": {"positions": 2e-4}, "delay_periods": 1, "seed": 3, ...}, see `sensing()`); its delay must be
        shorter than the run (a SpecError naming sensing.delay_periods).

        `fast`: the controller's fast path (docs/controller.md, "The fast path"): one compiled function per control
        step, generated and compiled into the cache on first use of a method; the same results (MLM to round-off,
        the penalty methods to ~1e-9, their more accurate operation order), integral action and limits exactly as
        the reference per-term path (the default), which takes every step with a limit in the way."""
        if not isinstance(fast, bool):
            raise ValueError(f"fast: expected True or False, found {fast!r}")
        name = self.method_name(method, iterations)
        gains = self.gains(**overrides)
        chosen = self.sensing(sensing)
        path = self.desired(trajectory, duration)
        duration = _duration(path, duration)
        self.check_delay(chosen, duration)
        data = self.model.data()  # this run's own buffers: nothing it writes is another run's
        start = self.equilibrium(trajectory, duration)
        engine = setup_default(data, path, plant_params, plant, mujoco_timestep, self.equilibrium())
        controller = make_controller(name, data, path, gains, fast=fast)
        rest = np.zeros(self.layout.n)
        for _ in range(warm_up):  # steady-state step times: the first calls page code in
            controller.compute(start.q, rest, 0.0)
        controller.reset()  # the run starts with the integral action's z = 0
        run = simulate(data, path, controller, engine, start.q, duration,
                       self.spec.controller.rate_hz, self.spec.simulation.step, progress=progress,
                       allow_divergence=True, sensor=make_estimator(data, path, chosen, fast=fast))
        return Result(run, self.layout, self.scenario, self.name)

    def simulate_open_loop(self, inputs, duration: float, trajectory: Trajectory | None = None,
                           plant: str = "own", plant_params: Mapping[str, float] | None = None,
                           mujoco_timestep: float | None = None, qd0=None,
                           progress: Callable[[int], object] | None = None) -> Result:
        """The plant driven open loop from the static start (docs/plant.md).

        `inputs`: a function t -> u (one value per input, `crane.inputs`, in N or N·m) evaluated at each
        control instant and held for the control period, or an array with one row per control
        instant. The spec's input limits are not applied (they are what the user asks): the summary's
        `inputs_outside_limits` lists the instants outside them. The moving anchors follow
        `trajectory`, by default held where the spec's path starts (the climbing unit at rest).
        `qd0`: initial velocities (default at rest), projected onto the constraints (the nearest velocity
        in the mass matrix's metric with every constraint rate zero: a start that would stretch or
        compress a cable at once is no state of the crane). `plant`, `plant_params`, `mujoco_timestep` as in
        `simulate`. A broken plant invariant (a slack cable stretched, a taut one pushing, energy not
        balanced) or a state that leaves any sensible motion ends the run there (`result.diverged_at`,
        the reason in `result.summary()` and `result.run.divergence`). Tracking figures are taken
        against the path the anchors follow."""
        if isinstance(duration, bool) or not (isinstance(duration, numbers.Real) and math.isfinite(duration)
                                              and duration > 0):
            raise ValueError(f"duration: expected a positive number of seconds, found {duration!r}")
        rate = self.spec.controller.rate_hz
        if not 1 <= round(duration * rate) <= MAX_CONTROL_STEPS:
            raise ValueError(f"duration: {duration:g} s is {round(duration * rate)} control steps at {rate:g} Hz: give "
                             f"between one ({1 / rate:g} s) and {MAX_CONTROL_STEPS}")
        path = (held_path(self.spec, self.layout, self.path, float(duration)) if trajectory is None
                else self.desired(trajectory, duration))
        if qd0 is not None:
            try:
                qd0 = np.asarray(qd0, dtype=float)
            except (TypeError, ValueError):
                qd0 = None
            if qd0 is None or qd0.shape != (self.layout.n,) or not np.isfinite(qd0).all():
                raise ValueError(f"qd0: expected {self.layout.n} finite velocities (crane.coordinates' order)")
        data = self.model.data()  # this run's own buffers
        start = self.equilibrium(trajectory, duration)
        engine = setup_default(data, path, plant_params, plant, mujoco_timestep, self.equilibrium())
        if qd0 is not None:  # the own plant's projection, whichever plant runs (same parameters)
            own = engine if plant == "own" else setup_default(data.data(), path, plant_params)
            qd0 = own.consistent_velocity(start.q, qd0)
        run = simulate_open_loop(data, path, engine, start.q, inputs, float(duration),
                                 self.spec.controller.rate_hz, self.spec.simulation.step, qd0=qd0, progress=progress)
        return Result(run, self.layout, self.scenario, self.name)


class Controller:
    """One of the crane's controllers for a plant of your own: `u = controller.step(q, qd, t)`.

    q and q̇ are the natural coordinates in `crane.coordinates` order; u is in `inputs` order (a new
    array each call). After a step, `limit_state` says which inputs sit on a limit (−1 lower, +1
    upper) and `saturated()` whether a limit kept the input from what the task asked."""

    def __init__(self, inner, inputs: list[str]):
        self._inner, self.inputs, self.name = inner, inputs, inner.name

    def step(self, q: np.ndarray, qd: np.ndarray, t: float) -> np.ndarray:
        """The input at measured coordinates q, rates qd (n each, `coordinates` order) and time t (s).
        Non-finite or mis-shaped measurements are a ValueError: they never reach the actuators."""
        n = self._inner.n
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        for name, value in (("q", q), ("qd", qd)):
            if value.shape != (n,):
                raise ValueError(f"{name}: expected {n} numbers (crane.coordinates order), found shape {value.shape}")
            if not np.isfinite(value).all():
                raise ValueError(f"{name}: expected finite numbers, found NaN or infinity")
        if not math.isfinite(t):
            raise ValueError(f"t: expected a finite time in seconds, found {t}")
        return self._inner.compute(q, qd, float(t)).copy()

    @property
    def limit_state(self) -> np.ndarray:
        return self._inner.limit_state.copy()

    def saturated(self) -> bool:
        return bool(self._inner.saturation())

    @property
    def integral(self) -> np.ndarray:
        """z = ∫σ dt per servo-constraint, the integral action's state (zero while ki = 0)."""
        return self._inner.integral.copy()

    @property
    def qdd(self) -> np.ndarray:
        """The accelerations q̈ the last step commanded (`coordinates` order): with the constraint and task
        accelerations, how soft a penalty method's constraints are (|φ_q q̈ + ρ| = |λ|/α̃)."""
        return np.array(self._inner.qdd, copy=True)

    def reset(self) -> None:
        """z = 0: before a new run (a step at an earlier time than the last one also resets it)."""
        self._inner.reset()

    def __repr__(self) -> str:
        return f"<Controller {self.name}: inputs {', '.join(self.inputs)}>"


def _duration(path: DesiredPath, duration: float | None) -> float:
    """The run's length: the path's, or a positive finite number of seconds (checked before any work)."""
    if duration is None:
        return path.duration
    if isinstance(duration, bool) or not isinstance(duration, numbers.Real) or not math.isfinite(duration) \
            or duration <= 0:
        raise ValueError(f"duration: expected a positive number of seconds, found {duration!r}")
    return float(duration)
