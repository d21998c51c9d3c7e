"""The plant: forward dynamics as an index-1 DAE with Baumgarte stabilisation (docs/model.md §8), with
cables that only pull.

    [M  φ_qᵀ] [q̈]   [H u − c                ]
    [φ_q  0 ] [λ] = [−γ − 2ζ_B ω_B φ̇ − ω_B² φ]      over the rigid rows and the TAUT cables

integrated with fixed-step RK4 for a held input u. The whole RK4 step is one generated C function
(acroboter.codegen.plant_step.plant_step_function), written independently of the controllers: it shares only the
symbolic model. Alongside q and q̇ it integrates the work of the inputs, the work of the moving
anchors through the constraint forces (λᵀφ_t) and the energy dissipated by damping. State
x = [q, q̇, W_u, W_anchor, E_d].

Cables only pull: the generated step takes a taut/slack mask and flags a taut cable that would push
or a slack one that ends stretched; those substeps (rare) are resolved by the event logic of
acroboter.sim.cable_events (force- and velocity-level complementarity, located re-tensions,
inelastic impacts, cascades), whose docstring says how and why. This module checks the energy
balance (ENERGY_TOL_REL) at the end of every control period and of every substep with an event.

Physical parameters. The plant may differ from the controller's model: `parameters` (name -> value,
acroboter.model.physical: masses, inertias, body points, fixed cable lengths, drum inertias, damping,
gravity) replace the spec's in everything the plant evaluates, the RK4 step (`plant_step`) and the
terms of its events, impacts and energy (`plant_terms`, `plant_energy`), all generated with the
parameters as a run-time input. The controller keeps the spec's. A plant with points or lengths
other than the spec's starts where the controller's model is at rest: its constraints are off by
the difference there, and Baumgarte stabilisation closes them (critically damped, ω_B = 20 /s: to
2 % in 0.3 s).
"""

from __future__ import annotations

import ctypes
import logging

import numpy as np

from ..control.path import DesiredPath
from ..model.physical import DRUM_END_M, PlantParameterError, drum_capacities, parameter_names, resolve, with_parameters
from ..runtime.compiled import StaleModelError
from .cable_events import (  # noqa: F401 - the plant's errors, events and tolerances are imported from here
    GAP_TOL,
    PUSH_TOL_REL,
    START_SLACK_GAP,
    STRETCH_TOL,
    TENSION_TOL_REL,
    CableEvent,
    CableEvents,
    InvariantError,
    SimulationError,
)
from .plant_refinement import EnergyBalanceError, StepRefinement

log = logging.getLogger(__name__)


class DrumCapacityError(SimulationError):
    """A winch paid out its drum's whole cable (`winch.capacity`, acroboter.model.physical.drum_capacities): both
    plants stop there, with the same words (`drum_ran_out`)."""


def drum_ran_out(cable: str, length: float, capacity: float, t: float) -> DrumCapacityError:
    return DrumCapacityError(f"at t = {t:.3f} s cable {cable} is paid out to {length:.3f} m, the end of what its drum "
                             f"holds (winch.capacity = {capacity:.3f} m): the run stops there")


_LOOP_REFUSED: set = set()  # cache roots where the C substep loop could not be built (warned once)

# |energy balance residual| allowed: ENERGY_TOL_REL × (weight × longest cable + peak kinetic energy), see
# Plant.energy_bound (2.6e-3 J at rest on the default crane; what runs reach: docs/plant.md, plant-fuzz.md).
ENERGY_TOL_REL = 1e-5
STANDARD_GRAVITY = 9.81  # m/s²: the energy scale's gravity when the spec's is weaker (or 0)
ROUNDING_ULPS = 1e3  # the balance's rounding: a thousand ulps of its terms' magnitudes (many steps' worth)
# The plant's constraints count as closed below this max |φ| (m² for a cable row, |d|² − L²; unitless for
# a body's axes): a start off them is checked for energy only from there (Plant._check_energy).
CLOSED_TOL = 1e-9


class StageTable(np.ndarray):
    """The stage signal table with the time of its first row (`t0`), see Plant.stage_table."""

    t0: float | None = None

    def __array_finalize__(self, obj):
        self.t0 = None  # a view or slice does not start where its parent does


def stage_table(path: DesiredPath, t0: float, h: float, steps: int) -> StageTable:
    """The path's signals at t0 + j·h/2 for j = 0..2·steps: RK4 step i reads rows 2i, 2i+1, 2i+2."""
    table = np.ascontiguousarray(path.table(t0 + 0.5 * h * np.arange(2 * steps + 1))).view(StageTable)
    table.t0 = float(t0)
    return table


def stage_rows(path: DesiredPath, h: float, first_step: int, steps: int) -> StageTable:
    """The rows of stage_table(path, 0, h, ·) for RK4 steps first_step .. first_step + steps − 1, alone:
    the same times to the bit (0.5·h·j for the same j), for a run evaluated in chunks."""
    times = 0.5 * h * np.arange(2 * first_step, 2 * (first_step + steps) + 1)
    table = np.ascontiguousarray(path.table(times)).view(StageTable)
    table.t0 = float(first_step * h)
    return table


class Plant(CableEvents, StepRefinement):
    def __init__(self, model, path: DesiredPath, zeta: float, omega: float, parameters=None):
        """The plant of `model`'s crane; `parameters` (name -> value, acroboter.model.physical) replace the
        spec's physical parameters in it (checked here: PlantParameterError; fixed for its lifetime)."""
        self.model, self.path = model, path
        # The path's [s, ṡ, s̈] at the few instants of an event: its rows (the table's numbers, cheaper), else its table
        self._path_rows = getattr(path, "rows", None) or (lambda times: path.table(np.array(times, dtype=float)))
        self.zeta, self.omega = zeta, omega
        # The crane the plant simulates: the spec with its parameters (validated as a spec).
        self.physical_spec = with_parameters(model.spec, parameters or {})
        self.parameters: dict[str, float] = {name: float(v) for name, v in (parameters or {}).items()}
        self._params = self._parameter_vector(model)
        lay = model.layout
        self.n = lay.n
        self.ns = lay.n_signals
        self.state_size = 2 * self.n + 3
        self._bind(model)
        self.cable_names = [c.name for c in model.spec.cables]
        nc = len(self.cable_names)
        self._active = np.ones(nc)
        self._step.point_input(self._step_inputs.index("cable_active"), self._active.ctypes.data)
        out = self._step.outputs
        self._x_next, self._tension, self._gap, self._events = (
            out["x_next"], out["cable_tension"], out["cable_gap"], out["cable_events"])
        self._cable_layout(model)
        # (coordinate index, capacity, cable) of each winch: a run stops where a cable reaches its drum's end
        capacity = drum_capacities(self.physical_spec)
        self._drums = [(lay.winch_index[name], capacity[name], name) for name in capacity]
        self._stage_scratch = np.zeros(9 * self.ns)
        self._minv: np.ndarray | None = None
        self.max_events_per_step = 50 * nc + 50
        # Per run (reset by initial_state):
        self.start_tension = np.zeros(nc)  # tensions at the start of the first substep of the last advance
        self.start_active = np.ones(nc)  # the mask that substep used
        self.impact_energy = 0.0  # J, Σ (T⁺ − T⁻) over the impacts
        self.transitions = np.zeros(nc, dtype=np.int64)
        self.events: list[CableEvent] = []
        self.cable_gap = np.zeros(nc)  # m, |p_a − p_b| − L of every cable at the end of the last advance
        self.energy_residual = 0.0  # J, at the end of the last advance (see energy_balance)
        self._energy_start, self._potential_scale, self._peak_kinetic, self._peak_terms = 0.0, 1.0, 0.0, 0.0
        self.closing = False  # started off its constraints, Baumgarte still closing them (_check_energy)
        self.energy_checked_from: float | None = 0.0
        self._compiled = self._compiled_loop(model)  # None where it cannot be had
        self._loop = self._compiled  # the loop in use: the compiled one, or None for Python's
        self._stage_at = self._stage.ctypes.data
        self._table, self._table_at = None, (0, 0, False)  # the last advance's table (held: its address stays valid)
        self._init_refinement()

    def _bind(self, model) -> None:
        """Its own bindings of the generated plant step, terms and energy, reading this plant's parameters."""
        # Without parameters of its own the plant is the spec's crane: the folded step and the model's
        # own terms, bit for bit the plant before parameters were an input (and ~20 % cheaper).
        functions = model.manifest["functions"]
        nominal = not self.parameters
        step = "plant_step_folded" if nominal and "plant_step_folded" in functions else "plant_step"
        terms, energy = ("model_terms", "energy") if nominal else ("plant_terms", "plant_energy")
        names = self._step_inputs = [name for name, _ in functions[step]["inputs"]]
        # A binding of its own: its outputs and its mask input are this plant's, not shared.
        self._step = model.bind(step)
        self._stage_input = names.index("stage_signals")
        self._x, self._u = model.buffers["x"], model.buffers["u"]
        self._settings = model.buffers["settings"]
        self._stage = model.buffers["stage_signals"]
        if "plant_params" in names:
            self._step.point_input(names.index("plant_params"), self._params.ctypes.data)
        # Its own bindings of the plant's terms and energy, reading this plant's parameters.
        self._terms = model.bind(terms)
        self._energy = model.bind(energy)
        for fn, function in ((self._terms, terms), (self._energy, energy)):
            inputs = [name for name, _ in functions[function]["inputs"]]
            if "plant_params" in inputs:
                fn.point_input(inputs.index("plant_params"), self._params.ctypes.data)

    def _cable_layout(self, model) -> None:
        """Which constraint row, winch and length each cable has, and the tolerances scaled by the crane's weight."""
        lay, nc = model.layout, len(self.cable_names)
        rows = list(model.manifest["layout"]["independent_constraint_rows"])
        self._rows = rows
        self._cable_row = [lay.constraints.index(f"cable {name}") for name in self.cable_names]
        self._modelled = [c for c in range(nc) if self._cable_row[c] in rows]
        self._body_rows = [r for r in rows if r not in self._cable_row]
        self._winch = [lay.winch_index.get(c.name) for c in model.spec.cables]
        self._fixed_length = [c.length for c in self.physical_spec.cables]
        physical = self.physical_spec
        mass = sum(b.mass for b in physical.bodies)
        weight = mass * float(np.linalg.norm(physical.gravity))
        self.tension_tol = TENSION_TOL_REL * max(1.0, weight)
        self.push_tol = PUSH_TOL_REL * max(1.0, weight)
        # the crane's energy scale's weight: in at least Earth's gravity (without gravity the scale is not 0)
        self._scale_weight = max(weight, mass * STANDARD_GRAVITY)
        self.gap_tol = GAP_TOL

    def _compiled_loop(self, model):
        """(the C substep loop, its buffers) over this plant's bound step (acroboter.runtime.plant_loop), or
        None: another backend's step, or no library (Python's loop then runs: the same numbers, slower)."""
        from ..runtime.compile_library import BuildError
        from ..runtime.compiled import BoundFunction, DamagedLibraryError
        from ..runtime.plant_loop import LoopBuffers, load_plant_loop

        if not isinstance(self._step, BoundFunction) or getattr(model, "cache_root", None) is None:
            return None
        try:
            advance = load_plant_loop(model.cache_root)
        except (BuildError, OSError, DamagedLibraryError) as err:
            if model.cache_root not in _LOOP_REFUSED:  # said once per process, not once per plant of a study
                _LOOP_REFUSED.add(model.cache_root)
                log.warning("the plant's substep loop runs in Python (the same numbers, slower): %s", err)
            return None
        step = self._step
        buffers = LoopBuffers(
            step=ctypes.cast(step._fn, ctypes.c_void_p).value, arg=step._call_args[0], res=step._call_args[1],
            iw=step._call_args[2], w=step._call_args[3], stage_slot=self._stage_input, nx=self.state_size,
            nc=len(self.cable_names), state=self._x.ctypes.data, x_next=self._x_next.ctypes.data,
            events=self._events.ctypes.data, tension=self._tension.ctypes.data, active=self._active.ctypes.data,
            start_tension=self.start_tension.ctypes.data, start_active=self.start_active.ctypes.data)
        return advance, buffers, ctypes.addressof(buffers)

    def use_compiled_loop(self, on: bool = True) -> bool:
        """Run the substeps in C (the default where the library builds) or in Python's loop (the reference the
        tests compare it with, bit for bit); whether the C loop is now used."""
        self._loop = self._compiled if on else None
        return self._loop is not None

    def _parameter_vector(self, model) -> np.ndarray:
        """The `plant_params` input: the physical spec's values in the order the library takes them
        (empty for a library generated with its parameters folded in, which takes no overrides)."""
        names = list(model.manifest["layout"].get("plant_parameters", []))
        if not names:
            if self.parameters:
                raise PlantParameterError(f"the plant of '{model.spec.name}' in {model.source_dir} was generated "
                                          "with its physical parameters folded in: it takes no plant parameters")
            return np.zeros(0)
        if names != parameter_names(model.spec):
            raise StaleModelError(f"the plant parameters of {model.source_dir} are not the spec's: regenerate it "
                                  "with `make generate`")
        return resolve(model.spec, self.parameters)

    # --- state --------------------------------------------------------------------------------
    @property
    def cable_active(self) -> np.ndarray:
        """1.0 taut, 0.0 slack per spec cable (the generated step reads this very array)."""
        return self._active

    @cable_active.setter
    def cable_active(self, value) -> None:
        self._active[:] = value

    def initial_state(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> np.ndarray:
        """x at rest (or at qd0); resets the event records. Every cable starts taut but one whose ends
        are closer than its length (by more than START_SLACK_GAP): that one starts slack, and pulls
        only once its ends reach its length (taut, a Baumgarte term would push them apart)."""
        x = np.zeros(self.state_size)
        x[: self.n] = q0
        if qd0 is not None:
            x[self.n : 2 * self.n] = qd0
        for index, capacity, cable in self._drums:
            if q0[index] >= capacity - DRUM_END_M:
                raise DrumCapacityError(f"cable {cable} starts {q0[index]:.4g} m long, at or beyond the end of what "
                                        f"its drum holds (winch.capacity = {capacity:.4g} m)")
        self._active[:] = 1.0
        self.start_tension[:] = 0.0
        self.impact_energy = 0.0
        self.transitions[:] = 0
        self.events = []
        self.refined_periods, self.finest_step, self._refined_to = 0, None, None
        _, gap, _ = self._contact_state(x, 0.0)
        self._active[gap < -START_SLACK_GAP] = 0.0
        self.start_active[:] = self._active
        self.cable_gap[:] = gap
        n = self.n
        lengths = [self._length(c, x[:n]) for c in range(len(self.cable_names))]
        self._potential_scale = self._scale_weight * max(lengths, default=1.0)  # the crane's energy scale
        self._peak_kinetic = 0.0
        self._peak_terms = 0.0  # the largest Σ|term| of the balance so far: its rounding
        self._energy_start = self.mechanical_energy(x[:n], x[n : 2 * n])
        self.energy_residual = 0.0
        self.closing = self._constraint_violation(x, 0.0) > CLOSED_TOL
        self.energy_checked_from = None if self.closing else 0.0  # s: when the energy check began
        return x

    def _constraint_violation(self, x: np.ndarray, t: float) -> float:
        """max |φ| over the rows the plant enforces (the rigid rows and the taut cables)."""
        phi = self._terms_at(x, t)["phi"]
        rows = self._body_rows + [self._cable_row[c] for c in self._modelled if self._active[c] == 1.0]
        return float(np.abs(phi[rows]).max()) if rows else 0.0

    def consistent_velocity(self, q: np.ndarray, qd: np.ndarray, t: float = 0.0) -> np.ndarray:
        """qd projected (in the mass matrix's metric) onto φ̇ = 0 over the rigid rows and every cable,
        taut: the nearest velocity a start with every cable taut can have. Resets the event records."""
        x = self.initial_state(q, qd)
        self._project_rates(x, self._terms_at(x, t), list(self._modelled))
        self.initial_state(q)
        return x[self.n : 2 * self.n].copy()

    def stage_table(self, t0: float, h: float, steps: int) -> StageTable:
        return stage_table(self.path, t0, h, steps)

    def stage_rows(self, h: float, first_step: int, steps: int) -> StageTable:
        return stage_rows(self.path, h, first_step, steps)

    # --- stepping -----------------------------------------------------------------------------
    def advance(self, x: np.ndarray, u: np.ndarray, h: float, table: np.ndarray, first_step: int,
                steps: int, t0: float | None = None) -> None:
        """`steps` RK4 steps of x (in place) with u held, stage signals from `table`; a period the step cannot
        resolve is flown again at a finer one (acroboter.sim.plant_refinement).

        Substep i runs from t0 + i·h; t0 is the table's (stage_table records it), else 0.
        """
        if t0 is None:
            t0 = getattr(table, "t0", None)
            t0 = 0.0 if t0 is None else t0
        try:
            residual = self._fly_period(x, u, h, table, first_step, steps, t0)
            self.cable_gap[:] = self._gap
            for index, capacity, cable in self._drums:
                if x[index] >= capacity - DRUM_END_M:
                    raise drum_ran_out(cable, float(x[index]), capacity, t0 + (first_step + steps) * h)
            self._check_energy(x, t0 + (first_step + steps) * h, residual)
        finally:
            self._refined_to = None

    def _run_substeps(self, x: np.ndarray, u: np.ndarray, h: float, table: np.ndarray, first_step: int,
                      steps: int, t0: float) -> None:
        """The substeps of advance at step h, x in place, without the period's end checks."""
        self._x[:] = x
        self._u[:] = u
        settings = self._settings
        settings[0], settings[1], settings[2] = h, self.zeta, self.omega
        if table is not self._table:  # a new table (every STAGE_CHUNK periods of a run): its address, once
            self._table, self._table_at = table, (table.ctypes.data, table.strides[0], table.flags.c_contiguous)
        base, row_bytes, contiguous = self._table_at
        try:
            if self._loop is not None and contiguous:
                self._advance_compiled(t0, h, base, row_bytes, first_step, steps)
            else:
                self._advance_python(t0, h, base, row_bytes, first_step, steps)
        finally:
            self._step.point_input(self._stage_input, self._stage_at)  # never leave a pointer into `table`
        x[:] = self._x

    def _advance_compiled(self, t0: float, h: float, base: int, row_bytes: int, first_step: int, steps: int) -> None:
        """The substeps in C (acroboter.runtime.plant_loop) up to each event, the events resolved here."""
        advance, buffers, address = self._loop
        buffers.tension_tol, buffers.gap_tol = self.tension_tol, self.gap_tol
        i, end = first_step, first_step + steps
        while i < end:
            i = advance(address, base, row_bytes, i, end, first_step)
            if i < 0:
                raise RuntimeError(f"{self._step.name} failed")
            if i < end:
                self._resolve(t0 + i * h, h, i == first_step, base + 2 * i * row_bytes)
                i += 1

    def _advance_python(self, t0: float, h: float, base: int, row_bytes: int, first_step: int, steps: int) -> None:
        """The substeps in Python: the reference the C loop is tested against."""
        step, point, stage_input = self._step.call, self._step.point_input, self._stage_input
        out, events, state = self._x_next, self._events, self._x
        tol, gap_tol = self.tension_tol, self.gap_tol
        for i in range(first_step, first_step + steps):
            point(stage_input, base + 2 * i * row_bytes)  # rows 2i..2i+2 are contiguous
            step()
            if events[0] > tol or events[1] > gap_tol:
                self._resolve(t0 + i * h, h, i == first_step, base + 2 * i * row_bytes)
                continue
            if i == first_step:
                self.start_tension[:] = self._tension
                self.start_active[:] = self._active
            state[:] = out

    def energy_balance(self, x: np.ndarray) -> float:
        """The residual of the energy balance at x (J): T + U − (T + U)₀ − (W_u + W_anchor − E_d +
        impact_energy), ≈ 0 to the integrator's accuracy when nothing is lost or created."""
        n = self.n
        kinetic, potential = self._energies(x[:n], x[n : 2 * n])
        self._peak_kinetic = max(self._peak_kinetic, kinetic)
        terms = (kinetic, potential, self._energy_start, x[2 * n], x[2 * n + 1], x[2 * n + 2], self.impact_energy)
        self._peak_terms = max(self._peak_terms, sum(abs(float(v)) for v in terms))
        return kinetic + potential - self._energy_start - (x[2 * n] + x[2 * n + 1] - x[2 * n + 2] + self.impact_energy)

    @property
    def energy_bound(self) -> float:
        """|energy residual| allowed (J): ENERGY_TOL_REL × (weight × longest cable + peak kinetic energy), the weight
        in at least STANDARD_GRAVITY, and never
        below the rounding of the balance's own terms (ROUNDING_ULPS of their largest sum of magnitudes): without
        gravity the weight is 0 and, at rest, so is the kinetic energy, and 1e-29 J of rounding failed the check."""
        return max(ENERGY_TOL_REL * (self._potential_scale + self._peak_kinetic),
                   ROUNDING_ULPS * np.finfo(float).eps * self._peak_terms)

    def _check_energy(self, x: np.ndarray, t: float, residual: float | None = None) -> None:
        """The energy invariant at x. A plant that starts off its constraints (its geometry differs
        from the model's, whose rest it starts at) is held to the balance from the instant Baumgarte
        has closed them (max |φ| ≤ CLOSED_TOL), against the energy there: the stabilisation's work
        while it closes them is no term of the balance (its residual is recorded, not checked)."""
        self.energy_residual = residual = self.energy_balance(x) if residual is None else residual
        if self.closing:
            if self._constraint_violation(x, t) <= CLOSED_TOL:
                self.closing = False
                self.energy_checked_from = t
                self._energy_start += residual
                self.energy_residual = 0.0
            return
        if not abs(residual) <= self.energy_bound:
            if self.refining:
                raise EnergyBalanceError(t)
            refined = f" (also at a step refined to {self._refined_to:g} s)" if self._refined_to else ""
            raise InvariantError(
                f"at t = {t:.6f} s the plant's energy balance is off by {residual:+.3e} J (bound "
                f"{self.energy_bound:.3e} J: {ENERGY_TOL_REL:g} of the crane's energy scale): energy was "
                f"created or lost without a cause{refined}; report the inputs that led here")

    def step(self, x: np.ndarray, t: float, u: np.ndarray, h: float) -> None:
        """One RK4 step of x (in place) from t to t + h (convenience; evaluates the path here)."""
        self.advance(x, u, h, self.stage_table(t, h, 1), 0, 1)

    def probe(self, x: np.ndarray, u: np.ndarray, t: float) -> None:
        """The cable tensions (start_tension, start_active) at state x and time t with input u, as a
        step from there would see them (taut cables that would push are marked slack); x is kept."""
        self._x[:] = x
        self._u[:] = u
        self._set_stage(t, 0.0)
        self._settings[:] = (0.0, self.zeta, self.omega)
        self._step.call()
        self._release_slack(t)
        self.start_tension[:] = self._tension
        self.start_active[:] = self._active
        self._step.point_input(self._stage_input, self._stage.ctypes.data)

    def mechanical_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        """T + U of the plant's crane (its parameters) at q, q̇."""
        return sum(self._energies(q, qd))

    def _energies(self, q: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
        """(T, U) of the plant's crane at q, q̇ (J): one call of its generated energy function."""
        self.model.q[:] = q
        self.model.qd[:] = qd
        self._energy.call()
        out = self._energy.outputs
        return float(out["kinetic"][0]), float(out["potential"][0])
