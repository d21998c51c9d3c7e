"""Differential fuzzing of the plant: open-loop experiments nobody chose, on the own plant and on MuJoCo.

Why: the own plant's cables switch between slack and taut by an event logic (acroboter.sim.plant) whose hard
cases are cables handing the load to each other; hand-picked scenarios missed a cascade that left a slack cable
stretched by 1.25 mm (issue 18). Here generated experiments run on the own plant and on MuJoCo (an engine
written by others, on the spec's MJCF model) must agree within stated bounds, with the own plant's invariants.

An experiment (`random_experiment`, from a `random.Random`, so that hypothesis can draw and shrink
it in tests/test_plant_fuzz.py and `make plant-fuzz` can replay it from a seed): a spec, 2-5 s, the
climbing unit at rest, per winch a random mix of its static tension, a sinusoid (amplitude up to
1.5x the static tension, 0.2-4 Hz, random phase), a step (up to 0.5x) and a pay-out pulse (2-20 ms,
a negative input: the drum pays cable out), the other inputs at their static values; random initial velocities projected
onto the constraints (both plants start from the same consistent state). Inputs are held for each
control period, as a controller's would be; the spec's limits are not applied (open loop).

What is compared, plant step by plant step (`compare`):
- the own plant's invariants (a broken one is an InvariantError: the case fails);
- the bodies' centres, outside +-RETENSION_WINDOW_S of every re-tension of either plant (MuJoCo's
  cable limits are soft: around an impact it is a stiff spring, not an impulse);
- each cable's slack/taut state at the end of every plant step, outside +-1 plant step of the own
  plant's transitions, from the cables' gaps (|p_a - p_b| - L): a cable is clearly slack where its
  gap is below -SLACK_GAP_M and clearly taut where it is above -TAUT_GAP_M; the states differ where
  one plant has a cable clearly slack and the other clearly taut (not from MuJoCo's limit forces, which
  flicker to zero for a step at a time 0.1-4 µm off the limit while the cable carries tens of newtons);
- the kinetic energy each impact takes (`impact_windows`, `replayed_loss`): the own plant's −(T⁺ − T⁻) of
  its re-tensions (CableEvent.delta_kinetic) against −(the work of MuJoCo's constraint forces) over a window
  around them (acroboter.sim.mujoco_energy: each MuJoCo step's energy balance, with what its soft limits
  store), within 1 % or 1e-4 J, MuJoCo restarted from the own plant's state 10 ms before the window: the
  same impact from the same state (along the two runs a light drum may arrive at its cable mm/s apart);
  where only an impact is off at the finest step tried, MuJoCo's figure extrapolated to step 0 from its two
  finest steps, if they show it converging on the own plant's at first order (acroboter.studies.impact_comparison).
A case whose crane leaves any sensible motion (a body 0.5 m off its start, a cable 0.5 m slack, a
drum paid out beyond what MuJoCo's model holds) is compared up to there, and the report says so.
"""

from __future__ import annotations

import math
import random
from dataclasses import asdict, dataclass, field

import numpy as np

from ..sim.plant import DrumCapacityError, InvariantError, SimulationError
from .impact_comparison import (  # noqa: F401 - the impact bounds are the fuzz's, read from here by its report
    IMPACT_BEFORE_S,
    IMPACT_ENERGY_J,
    IMPACT_ENERGY_REL,
    IMPACT_LEAD_S,
    agrees_extrapolated,
    impact_bound,
    impact_loss,
    impact_windows,
    replayed_loss,
)

# Agreement bounds (the issue's): positions (m), and the window around a re-tension left out of it (s).
POSITION_BOUND_M = 20e-6
RETENSION_WINDOW_S = 10e-3
MUJOCO_TIMESTEP = 5e-5  # s: MuJoCo converges on the own plant as its step shrinks (docs/plant.md)
# The damping ratio ζ of MuJoCo's cable limits, so that a snap taut is (nearly) inelastic, as the own plant's
# impact is (restitution 0). MuJoCo's limit is a unilateral damped spring in constraint space (its docs,
# "Solver parameters": r̈ = −b ṙ − k r at impedance ≈ 1, b = 2/timeconst, k = 1/(timeconst² ζ²)); started
# at contact with a closing speed v and no load, its force b ṙ + k r reaches 0, and the limit lets go,
# while the cable is still closing back at e·v: restitution e(ζ) = (s₁/s₂)·exp(s₁t*), s₁,₂ the roots of
# s² + bs + k, t* = 2 ln(s₂/s₁)/(s₁ − s₂): 13.5 % at the MJCF's ζ = 1, 4.8 % at 2, 1.4 % at 4, 0.38 % at 8,
# 0.097 % at 16 (~1/(4ζ²)). The price is a slow mode: the stretch a snap leaves creeps back with a time
# constant of ~2·timeconst·ζ² = 4hζ² (timeconst = 2h, h MuJoCo's step), which must stay well inside the
# RETENSION_WINDOW_S that positions are not compared in. So ζ = √(CABLE_CREEP_S / 4h): the creep is
# CABLE_CREEP_S at every step and the restitution ~h/CABLE_CREEP_S vanishes with the step, as the
# compliance does (ζ = 3.6 at 5e-5 s: 2.1 %; 8 at 1e-5 s: 0.38 %). Measured on seed 906: docs/plant-fuzz.md.
CABLE_CREEP_S = 2.56e-3


def cable_dampratio(mujoco_timestep: float) -> float:
    """The damping ratio of MuJoCo's cable limits at its step (see CABLE_CREEP_S)."""
    return math.sqrt(CABLE_CREEP_S / (4.0 * mujoco_timestep))
# A case that disagrees at MUJOCO_TIMESTEP is run again with MuJoCo at each of CONFIRM_TIMESTEPS in turn; the
# verdict is the first that agrees, or the finest's: MuJoCo's compliant cables converge on the inextensible ones as
# its step shrinks, the own plant does not move with its own step (docs/plant.md, "Differential fuzzing": a light
# drum 3.9/0.96 mm off at 5e-5/1e-5 s; chains of impacts 25.5/9.3/7.5 µm off at 1e-5/5e-6/2.5e-6 s while the own
# plant at a quarter step moves 0.06 µm). Each step's worst difference is kept (Outcome.position_diff_by_step).
CONFIRM_TIMESTEPS = (1e-5, 5e-6)
DURATION_S = (2.0, 5.0)
MAX_AMPLITUDE = 1.5  # × the static tension
STEP = 0.5  # × the static tension, either way (a step by −1 leaves the load on nothing: it falls away)
FREQUENCY_HZ = (0.2, 4.0)
MAX_INITIAL_SPEED = 0.1  # m/s, of the random initial velocity (before projection onto the constraints)
PULSE_S = (0.002, 0.02)  # s: a pay-out pulse's length (a 0.05 kg drum at −40 N pays out 0.16 m in 20 ms)
# A body this far from its start, or a cable this slack, has left any sensible motion: the comparison
# stops there. (A drum that pays out metres of slack snaps back taut at tens of m/s, 170 J impacts that
# no winch survives, and where MuJoCo's compliant cable stretches by millimetres while it stops the drum.)
STRAY_M = 0.5
SLACK_GAP_M = 1e-5  # m: clearly slack (MuJoCo's soft limits move a taut cable's ends by up to ~4 µm)
TAUT_GAP_M = 1e-6  # m: clearly taut


@dataclass
class Experiment:
    spec: str  # an example's name (acroboter.example_spec)
    duration: float  # s
    programs: dict[str, list[list]] = field(default_factory=dict)  # input name -> components (see input_value)
    velocity_seed: int = 0
    velocity_scale: float = 0.0  # m/s
    seed: int | None = None  # the seed it was drawn from (make plant-fuzz), for the replay command

    def replay_command(self, mujoco_timestep: float = MUJOCO_TIMESTEP) -> str:
        if self.seed is not None:
            step = f" --mujoco-timestep {mujoco_timestep:g}" if mujoco_timestep != MUJOCO_TIMESTEP else ""
            crane = generated_seed(self.spec)
            which = (f"--cranes 1 --crane-seed {crane} --no-closed-loop" if crane is not None
                     else f"--spec {self.spec}")
            return (f"python -m acroboter.plant_fuzz {which} --seed {self.seed} --cases 1 --workers 1 "
                    f"--out results/plant_fuzz/replay-{self.spec}-{self.seed}{step}")
        return ("python -c 'from acroboter.studies.plant_differential import Experiment, run_experiment; "
                f"print(run_experiment(Experiment(**{asdict(self)!r})))'")


def random_experiment(spec_name: str, static: dict[str, float], winches: list[str], rng: random.Random,
                      seed: int | None = None) -> Experiment:
    """An experiment on `spec_name` whose winch inputs (names `winches`) are random mixes around their
    static values (`static`: every input's static value)."""
    # 2 decimals; the plants run whole control periods of it (round(duration / period) of them)
    duration = round(rng.uniform(*DURATION_S), 2)
    programs = {}
    for name in winches:
        level = float(abs(static[name])) or 1.0
        parts: list[list] = []
        if rng.random() < 0.7:
            # amplitude MAX_AMPLITUDE·U²: every size up to 1.5×, small ones more often (beyond 1× the winch
            # pays out under a negative input: its 0.05 kg drum runs off at hundreds of m/s²)
            parts.append(["sine", float(rng.random() ** 2 * MAX_AMPLITUDE * level), rng.uniform(*FREQUENCY_HZ),
                          rng.uniform(0.0, 2 * math.pi)])
        if rng.random() < 0.4:
            parts.append(["step", rng.uniform(0.0, duration), float(rng.uniform(-STEP, STEP) * level)])
        if rng.random() < 0.4:
            parts.append(["pulse", rng.uniform(0.0, duration), rng.uniform(*PULSE_S),
                          float(-rng.uniform(0.0, MAX_AMPLITUDE) * level - static[name])])
        programs[name] = parts
    return Experiment(spec_name, duration, programs, rng.randrange(2**31), rng.uniform(0.0, MAX_INITIAL_SPEED), seed)


def input_value(static: float, parts: list[list], t: float) -> float:
    """static + the components at t: ["sine", amplitude, Hz, phase], ["step", at s, by], ["pulse", at s,
    lasting s, by] (a pulse adds `by` while it lasts)."""
    u = static
    for kind, *args in parts:
        if kind == "sine":
            amplitude, frequency, phase = args
            u += amplitude * math.sin(2 * math.pi * frequency * t + phase)
        elif kind == "step":
            at, by = args
            u += by if t >= at else 0.0
        elif kind == "pulse":
            at, lasting, by = args
            u += by if at <= t < at + lasting else 0.0
        else:
            raise ValueError(f"unknown input component {kind!r}")
    return u


@dataclass
class Outcome:
    """How one experiment went: the figures compared and the verdict."""

    spec: str
    duration: float
    status: str  # "agrees" or "fails: ..." (over the part compared)
    max_position_diff_m: float = 0.0  # outside the re-tension windows
    slack_mismatch_steps: int = 0  # plant steps whose slack/taut state differs, outside ±1 step of a transition
    max_slack_stretch_m: float = 0.0  # the own plant's, at the end of any substep
    max_energy_ratio: float = 0.0  # |energy residual| / its bound, the own plant's
    retensions: int = 0  # the own plant's taut events
    transitions: int = 0  # the own plant's events
    replay: str = ""
    mujoco_timestep: float = MUJOCO_TIMESTEP  # s, of the verdict's MuJoCo run
    first_status: str = ""  # at MUJOCO_TIMESTEP (and any coarser confirming step), when the verdict needed a finer one
    position_diff_by_step: str = ""  # "step: worst difference (µm)" of each MuJoCo step run, when more than one
    compared_s: float = 0.0  # how much of it was compared: all of it, or up to where it left sensible motion
    left: str = ""  # why the comparison stopped early: a body 0.5 m off, a drum paid out beyond the model
    impacts: int = 0  # impacts whose kinetic energy loss was compared (a cascade counts once)
    impact_loss_own_j: float = 0.0  # the own plant's loss (−ΣΔT) in the impact of the worst agreement
    impact_loss_mujoco_j: float = 0.0  # MuJoCo's (−W of its constraint forces) in that impact
    max_impact_energy_ratio: float = 0.0  # worst |loss difference| / its bound (max(1 % own loss, 1e-4 J))
    refined_steps: int = 0  # plant steps the own plant flew again at a finer step (acroboter.sim.plant_refinement)
    # per impact compared: (its window's start and end, s; the own plant's loss, J; MuJoCo's, J); not a CSV column
    impact_records: list = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.status.startswith("fails")


def run_experiment(experiment: Experiment, crane=None, mujoco_timestep: float = MUJOCO_TIMESTEP,
                   confirm_timesteps: tuple[float, ...] = CONFIRM_TIMESTEPS) -> Outcome:
    """Both plants through `experiment`, step by plant step, and how they compare (see the module); a
    disagreement (not a broken invariant) is run again with MuJoCo at each of `confirm_timesteps` in turn (()
    none), and the verdict is the first that agrees, or the last's."""
    outcome = _compare(experiment, crane, mujoco_timestep)
    tried = [outcome]
    for finer_step in confirm_timesteps:
        if outcome.passed or outcome.status.startswith(("fails: invariant", "fails: MuJoCo")):
            break
        outcome = _compare(experiment, crane, finer_step)
        tried.append(outcome)
    if len(tried) > 1 and outcome.status.startswith("fails: an impact takes") and ";" not in outcome.status:
        # only an impact's energy is off, at the finest step: MuJoCo's figure at step 0 (acroboter.studies.
        # impact_comparison), where its two finest steps show it converging on the own plant's at first order
        extrapolated = agrees_extrapolated(outcome.impact_records, outcome.mujoco_timestep,
                                           tried[-2].impact_records, tried[-2].mujoco_timestep)
        if extrapolated:
            outcome.status = f"agrees ({extrapolated[0]})"
            outcome.max_impact_energy_ratio = extrapolated[1]
    if len(tried) > 1:
        outcome.first_status = "; ".join(f"at {o.mujoco_timestep:g} s: {o.status}" for o in tried[:-1])
        outcome.position_diff_by_step = ", ".join(f"{o.mujoco_timestep:g} s: {o.max_position_diff_m * 1e6:.1f} µm"
                                                  for o in tried)
        outcome.replay = tried[0].replay  # the replay runs the same steps
    return outcome


def _compare(experiment: Experiment, crane, mujoco_timestep: float) -> Outcome:
    """One experiment on both plants at `mujoco_timestep`: driven step by step (the own plant's invariants checked
    at every step), then judged: positions, slack/taut states, the energy each impact takes."""
    comparison = _Comparison(experiment, crane, mujoco_timestep)
    outcome = comparison.outcome
    try:
        steps = comparison.drive()
    except InvariantError as err:
        outcome.status = f"fails: invariant: {err}"
        return _finish(outcome, comparison.own)
    except SimulationError as err:  # MuJoCo failed otherwise (a non-finite state): no verdict is a failure
        outcome.status = f"fails: MuJoCo: {err}"
        return _finish(outcome, comparison.own)
    comparison.judge(steps)
    return _finish(outcome, comparison.own)


class _Comparison:
    """The own plant and MuJoCo from the same start under the same inputs, and what each step of each recorded."""

    def __init__(self, experiment: Experiment, crane, mujoco_timestep: float):
        from ..api.crane import Crane
        from ..sim.mujoco_plant import MujocoPlant
        from ..sim.open_loop import held_path
        from ..sim.plant import Plant

        self.experiment, self.mujoco_timestep = experiment, mujoco_timestep
        self.crane = crane = crane or Crane.from_example(experiment.spec)
        spec, lay = crane.spec, crane.layout
        self.start = crane.equilibrium()
        self.path = held_path(spec, lay, crane.path, experiment.duration)
        self.own = Plant(crane.model, self.path, spec.simulation.baumgarte_zeta, spec.simulation.baumgarte_omega)
        self.engine = MujocoPlant(crane.model, self.path, timestep=mujoco_timestep)
        self.engine.release_limits()
        self.engine.set_cable_dampratio(cable_dampratio(mujoco_timestep))
        self.period, self.h = 1.0 / spec.controller.rate_hz, spec.simulation.step
        self.substeps = round(self.period / self.h)
        self.periods = int(round(experiment.duration / self.period))
        self.bodies = [lay.body_offset[b.name] for b in spec.bodies]
        self.outcome = Outcome(experiment.spec, experiment.duration, "agrees",
                               replay=experiment.replay_command(mujoco_timestep), mujoco_timestep=mujoco_timestep)
        steps, cables = self.periods * self.substeps, len(self.own.cable_names)
        self.diff = np.zeros(steps)
        self.own_gap, self.mj_gap = np.zeros((steps, cables)), np.zeros((steps, cables))
        self.mj_changes: list[float] = []
        self.own_states = np.zeros((steps, 2 * self.own.n))  # the own plant's q, q̇ at the start of each plant step
        self.inputs = np.zeros((self.periods, len(lay.inputs)))

    def drive(self) -> int:
        """Both plants through the experiment's inputs, plant step by plant step: the steps compared (fewer where the
        crane left sensible motion or a drum ran out: compared up to there). InvariantError: the own plant broke
        one; SimulationError: MuJoCo failed."""
        own, lay, experiment = self.own, self.crane.layout, self.experiment
        static = dict(zip(lay.inputs, self.start.inputs, strict=True))
        qd0 = consistent_velocity(own, self.start.q, experiment)
        x, y = own.initial_state(self.start.q, qd0), self.engine.initial_state(self.start.q, qd0)
        i = 0
        try:
            for k in range(self.periods):
                t = k * self.period
                u = np.array([input_value(static[name], experiment.programs.get(name, []), t) for name in lay.inputs])
                self.inputs[k] = u
                table = own.stage_table(t, self.h, self.substeps)
                for j in range(self.substeps):
                    i = k * self.substeps + j
                    self._step(i, x, y, u, table, j, t)
        except (_Stray, DrumCapacityError) as err:  # the crane flew off, a drum ran out: compared up to there
            self.outcome.left = str(err)
            return i
        return self.periods * self.substeps

    def _step(self, i: int, x, y, u, table, j: int, t: float) -> None:
        own, engine, outcome, h = self.own, self.engine, self.outcome, self.h
        self.own_states[i] = x[: 2 * own.n]
        try:
            own.advance(x, u, h, table, j, 1)
        except (InvariantError, DrumCapacityError):
            raise
        except SimulationError as err:  # no consistent cable state: the own plant's failure
            raise InvariantError(str(err)) from None
        before = engine.start_active.copy()
        engine.advance(y, u, h, engine.stage_table(t + j * h, h, 1), 0, 1)
        self.own_gap[i], self.mj_gap[i] = own.cable_gap, engine.cable_gap
        if i and (engine.start_active != before).any():
            self.mj_changes.append(t + j * h)
        slack = own.cable_active == 0.0
        if slack.any():
            outcome.max_slack_stretch_m = max(outcome.max_slack_stretch_m, float(own.cable_gap[slack].max()))
        outcome.max_energy_ratio = max(outcome.max_energy_ratio, abs(own.energy_residual) / own.energy_bound)
        self.diff[i] = max(np.linalg.norm(x[b : b + 3] - y[b : b + 3]) for b in self.bodies)
        if max(np.linalg.norm(x[b : b + 3] - self.start.q[b : b + 3]) for b in self.bodies) > STRAY_M:
            raise _Stray(f"a body is more than {STRAY_M} m from its start at t = {t + (j + 1) * h:.3f} s")
        if own.cable_gap.min() < -STRAY_M:
            raise _Stray(f"cable {own.cable_names[int(np.argmin(own.cable_gap))]} is more than {STRAY_M} m "
                         f"slack at t = {t + (j + 1) * h:.3f} s")

    def judge(self, steps: int) -> None:
        """The verdict on the first `steps` plant steps: positions away from re-tensions, slack/taut states away
        from transitions, each impact's energy (MuJoCo replayed from the own state), within their bounds."""
        outcome, own, h = self.outcome, self.own, self.h
        outcome.compared_s = steps * h
        retension = [e.t for e in own.events if e.kind == "taut"] + self.mj_changes
        times = h * np.arange(1, steps + 1)  # the end of each plant step
        near = _near(times, retension, RETENSION_WINDOW_S)
        outcome.max_position_diff_m = float(self.diff[:steps][~near].max()) if (~near).any() else 0.0
        own_gap, mj_gap = self.own_gap[:steps], self.mj_gap[:steps]
        differ = (((own_gap < -SLACK_GAP_M) & (mj_gap > -TAUT_GAP_M))
                  | ((mj_gap < -SLACK_GAP_M) & (own_gap > -TAUT_GAP_M)))
        # after a re-tension MuJoCo's compliant impact may bounce (a violent snap of a light drum: ~1 mm for
        # a few steps, even overdamped), so the states are compared from RETENSION_WINDOW_S after it on
        settling = _near(times - 0.5 * RETENSION_WINDOW_S, retension, 0.5 * RETENSION_WINDOW_S)
        mismatch = differ.any(axis=1) & ~_near(times, [e.t for e in own.events], h) & ~settling
        outcome.slack_mismatch_steps = int(mismatch.sum())
        self._judge_impacts(steps)
        if outcome.status != "agrees":
            return
        problems = []
        if outcome.max_position_diff_m > POSITION_BOUND_M:
            problems.append(f"positions differ by {outcome.max_position_diff_m * 1e6:.1f} µm")
        if outcome.max_impact_energy_ratio > 1.0:
            problems.append(f"an impact takes {outcome.impact_loss_own_j:.4g} J in the own plant, "
                            f"{outcome.impact_loss_mujoco_j:.4g} J in MuJoCo")
        if outcome.slack_mismatch_steps:
            first = float(times[np.argmax(mismatch)])
            problems.append(f"slack/taut states differ in {outcome.slack_mismatch_steps} plant steps (first at "
                            f"t = {first:.3f} s)")
        if problems:
            outcome.status = "fails: " + "; ".join(problems)

    def _judge_impacts(self, steps: int) -> None:
        from ..sim.mujoco_energy import ConstraintWork
        from ..sim.mujoco_plant import MujocoPlant

        outcome, own, h = self.outcome, self.own, self.h
        replay = MujocoPlant(self.crane.model, self.path, timestep=self.mujoco_timestep)  # each impact again
        replay.release_limits()
        replay.set_cable_dampratio(cable_dampratio(self.mujoco_timestep))
        ledger = ConstraintWork(replay)
        for first, last in impact_windows(own.events, self.mj_changes, h, steps, RETENSION_WINDOW_S):
            own_loss = impact_loss(own.events, first, last, h)
            mj_loss = replayed_loss(replay, ledger, self.own_states, self.inputs, self.substeps, h, first, last)
            outcome.impacts += 1
            outcome.impact_records.append((first * h, last * h, own_loss, mj_loss))
            ratio = abs(mj_loss - own_loss) / impact_bound(own_loss)
            if ratio >= outcome.max_impact_energy_ratio:
                outcome.max_impact_energy_ratio = ratio
                outcome.impact_loss_own_j, outcome.impact_loss_mujoco_j = own_loss, mj_loss


class _Stray(Exception):
    pass


def _finish(outcome: Outcome, own) -> Outcome:
    outcome.retensions = sum(e.kind == "taut" for e in own.events)
    outcome.transitions = len(own.events)
    outcome.refined_steps = own.refined_periods
    return outcome


def _near(times: np.ndarray, events: list[float], window: float) -> np.ndarray:
    """Per time: whether an event is within ±window of it."""
    if not events:
        return np.zeros(times.shape, dtype=bool)
    marks = np.sort(np.asarray(events))
    right = np.searchsorted(marks, times - window, side="left")
    return (right < marks.size) & (marks[np.minimum(right, marks.size - 1)] <= times + window)


def consistent_velocity(plant, q0: np.ndarray, experiment: Experiment) -> np.ndarray:
    """A random velocity of about velocity_scale (m/s per body coordinate) made consistent with every
    constraint (Plant.consistent_velocity), so both plants start from the same consistent state."""
    rng = np.random.default_rng(experiment.velocity_seed)
    raw = rng.normal(size=plant.n) * experiment.velocity_scale / math.sqrt(3)
    return plant.consistent_velocity(q0, raw)


# ---------------------------------------------------------------------------------------------------
# Many experiments (acroboter.cli.plant_fuzz: `make plant-fuzz`, Dask, a progress bar): one case, the report

_CRANES: dict[str, object] = {}  # per worker process: a crane is loaded (not built) once


def crane_of(name: str):
    """An example's crane, or a generated one's (acroboter.model.crane_generator: "crane_<seed>")."""
    from ..api.crane import Crane
    from ..model.crane_generator import crane_spec

    if name not in _CRANES:
        seed = generated_seed(name)
        _CRANES[name] = Crane.from_example(name) if seed is None else Crane.from_spec(crane_spec(seed))
    return _CRANES[name]


def remember_crane(crane) -> None:
    """Keep `crane` for crane_of (a generated crane built by its task)."""
    _CRANES[crane.name] = crane


def generated_seed(name: str) -> int | None:
    """The generator's seed of a generated crane's name ("crane_<seed>"), None for an example's."""
    from ..model.crane_generator import crane_name
    from ..process.locations import example_names

    head, _, tail = name.rpartition("_")
    if tail.isdigit() and crane_name(int(tail)) == name and name not in example_names():
        return int(tail)
    return None


def experiment_of(name: str, seed: int) -> Experiment:
    """The experiment `make plant-fuzz` draws for (spec, seed): the replay of a reported case."""
    from ..model.spec import WinchTension

    crane = crane_of(name)
    lay = crane.layout
    static = {k: float(v) for k, v in zip(lay.inputs, crane.equilibrium().inputs, strict=True)}
    winches = [input_name for input_name, act in zip(lay.inputs, crane.spec.actuators, strict=True)
               if isinstance(act, WinchTension)]
    # a generated crane's experiments are drawn for it (the same seed on two cranes: two experiments)
    rng = random.Random(seed if generated_seed(name) is None else f"{name}/{seed}")
    return random_experiment(crane.spec.name, static, winches, rng, seed)


def run_case(case: tuple[str, int], mujoco_timestep: float = MUJOCO_TIMESTEP) -> dict:
    """One (spec, seed) case as a row of the report (a task: module level, so that it pickles)."""
    name, seed = case
    return outcome_row(run_experiment(experiment_of(name, seed), crane_of(name), mujoco_timestep), seed)


def outcome_row(outcome: Outcome, seed: int) -> dict:
    """An experiment's outcome as a row of plant_fuzz.csv (COLUMNS; its per-impact records are no column)."""
    row = asdict(outcome)
    del row["impact_records"]
    row["seed"] = seed
    row["passed"] = outcome.passed
    return row


COLUMNS = ["spec", "seed", "duration", "compared_s", "passed", "status", "mujoco_timestep", "first_status",
           "position_diff_by_step",
           "max_position_diff_m", "slack_mismatch_steps", "max_slack_stretch_m", "max_energy_ratio", "retensions",
           "transitions", "impacts", "max_impact_energy_ratio", "impact_loss_own_j", "impact_loss_mujoco_j", "left",
           "refined_steps", "replay"]
