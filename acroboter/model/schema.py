"""The spec's schema: one pydantic model per TOML table, with the field-level checks (types, unknown keys,
ranges, inertia) as validators, and the caps that bound every command's work. What needs the whole spec
(names that refer to each other) is acroboter.model.spec_checks; acroboter.model.spec reads a file with both.
"""

from __future__ import annotations

import hashlib
import json
import math
from typing import Annotated, Any, Literal, get_args

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    create_model,
    field_validator,
)
from pydantic_core import PydanticCustomError

from .controller_parameters import RECOVERIES, SATURATIONS, table_fields  # noqa: F401 (the spec's names)
from .ranges import (
    ANGLE,
    BAUMGARTE_OMEGA,
    BAUMGARTE_ZETA,
    CABLE_LENGTH,
    COORDINATE,
    DAMPING,
    DELAY,
    GAIN,
    GRAVITY,
    INERTIA,
    INITIAL_YAW,
    ITERATIONS,
    LIMIT,
    MASS,
    MAX_AXIS_RATE,
    MAX_COAST,
    MAX_SPEED,
    MEAN_SPEED,
    NOISE,
    PATH_YAW,
    PREFERRED,
    PROJECTION_ITERATIONS,
    QUANTIZATION,
    RADIUS,
    RATE,
    REFLECTED_INERTIA,
    SEED,
    STEP,
    VELOCITY_FILTER,
)

AXES = ("u", "v", "w")
# Caps that keep every command's work and memory bounded (checked here, once, before any work).
MAX_NAME_LENGTH = 64  # a name is a folder, a file name prefix and a C symbol prefix
MAX_ITERATIONS = ITERATIONS.high  # iterative penalty: far beyond where it stops improving (~10)
MAX_CONTROL_STEPS = 360_000  # 2 hours at 50 Hz: about 200 MB of records for the default crane
MAX_PLANT_SUBSTEPS = 10_000  # plant steps per control period
# A wide SI window for physical magnitudes: outside it a number is a unit mistake, not a crane. Every numeric
# field has its Range (acroboter.model.ranges: bounds, unit, why), checked by pydantic in the same words.
MASS_RANGE = (MASS.low, MASS.high)  # kg
LENGTH_LIMIT = COORDINATE.high  # m, for positions, points and cable lengths
MIN_PRINCIPAL_MOMENT = 1e-12  # kg·m²: a milligram 1 mm from the axis (the lightest body at a small radius)
# J = ½ tr(I) E − I must stay well conditioned (it is the axes' part of M): I1 + I2 − I3 at least
# this fraction of I3 (a flat lamina, I1 + I2 = I3, makes M singular).
INERTIA_MARGIN = 1e-6
PATH_SIGNALS = ("x", "y", "z", "yaw")
# The task's components, as a saturation priority names them: a position task's x and y, its z, the level
# task's two rows, the yaw task's row (acroboter.model.spec_checks.task_components).
TASK_COMPONENTS = ("horizontal", "height", "level", "yaw")
NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"


class SpecError(Exception):
    """A spec that cannot be used; `problems` lists (field path, message) pairs."""

    def __init__(self, source: str, problems: list[tuple[str, str]]):
        self.source = source
        self.problems = problems
        lines = [f"invalid model spec {source}:"]
        lines += [f"  {path}: {msg}" for path, msg in problems]
        super().__init__("\n".join(lines))


class _Strict(BaseModel):
    # strict: a TOML string or boolean is never silently taken for a number (integers are fine
    # where a float is expected); no inf/nan either.
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


def _exactly(count: int, what: str):
    def check(value: list) -> list:
        if len(value) != count:
            message = f"expected {what}, found {{found}} item(s)"
            raise PydanticCustomError("wrong_length", message, {"found": len(value)})
        return value

    return AfterValidator(check)


Vec3 = Annotated[list[INERTIA.field()], _exactly(3, "3 numbers [x, y, z]")]  # a row of an inertia tensor
Coordinate = COORDINATE.field()
Position = Annotated[list[Coordinate], _exactly(3, "3 numbers [x, y, z]")]  # m
Mass = MASS.field()
Length = CABLE_LENGTH.field()
Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=MAX_NAME_LENGTH)]


class PolarPoint(_Strict):
    """A point in the body's xy-plane given by radius and angle, lifted by `height` along w."""

    radius: RADIUS.field()
    angle_deg: ANGLE.field()
    height: Coordinate = 0.0

    def xyz(self) -> list[float]:
        a = math.radians(self.angle_deg)
        return [self.radius * math.cos(a), self.radius * math.sin(a), self.height]


def _point_form(value: Any) -> str | None:
    if isinstance(value, dict | PolarPoint):
        return "polar"
    if isinstance(value, list | tuple):
        return "xyz"
    return None  # neither: one readable error instead of one per union branch


POINT_FORMS = "[x, y, z] in body axes or a table {radius, angle_deg, height}"
BodyPoint = Annotated[
    Annotated[Position, Tag("xyz")] | Annotated[PolarPoint, Tag("polar")],
    Discriminator(_point_form, custom_error_type="point_form", custom_error_message=f"expected {POINT_FORMS}"),
]


class Damping(_Strict):
    translational: DAMPING.field() = 0.0  # N·s/m on the centre-of-mass velocity
    rotational: DAMPING.field() = 0.0  # N·m·s on the angular velocity


class Body(_Strict):
    name: Name
    mass: Mass
    inertia: Annotated[list[Vec3], _exactly(3, "a 3x3 matrix (3 rows of 3 numbers)")]
    initial_position: Position
    initial_yaw_deg: INITIAL_YAW.field() = 0.0
    damping: Damping = Damping()
    points: dict[Name, BodyPoint] = {}
    redundant_constraints: bool = False  # add w - u x v = 0 on top of the six orthonormality rows

    @field_validator("inertia")
    @classmethod
    def _inertia_is_physical(cls, value: list[list[float]]) -> list[list[float]]:
        i_g = np.array(value, dtype=float)
        if not np.allclose(i_g, i_g.T, rtol=0, atol=1e-12 * max(1.0, np.abs(i_g).max())):
            asym = [(a, b) for a in range(3) for b in range(a + 1, 3) if i_g[a, b] != i_g[b, a]]
            pairs = ", ".join(f"[{a}][{b}] = {i_g[a, b]:g} but [{b}][{a}] = {i_g[b, a]:g}" for a, b in asym)
            raise ValueError(f"expected a symmetric inertia tensor, found {pairs}")
        moments = np.linalg.eigvalsh(i_g)
        shown = ", ".join(f"{m:.6g}" for m in moments)
        if moments[0] <= 0:
            raise ValueError(f"expected a positive definite inertia tensor (kg·m²), found principal moments {shown}")
        if moments[0] < MIN_PRINCIPAL_MOMENT:
            raise ValueError(f"expected principal moments of at least {MIN_PRINCIPAL_MOMENT:g} kg·m² (a milligram 1 mm "
                             f"from the axis), found principal moments {shown}")
        if moments[0] + moments[1] < moments[2] * (1 - 1e-12):
            raise ValueError(
                "expected principal moments that satisfy the triangle inequality I1 + I2 >= I3, "
                f"found principal moments {shown} ({moments[0]:.6g} + {moments[1]:.6g} < {moments[2]:.6g})"
            )
        if moments[0] + moments[1] - moments[2] < INERTIA_MARGIN * moments[2]:
            j = 0.5 * np.array([moments[1] + moments[2] - moments[0], moments[0] + moments[2] - moments[1],
                                moments[0] + moments[1] - moments[2]])
            condition = j.max() / j.min() if j.min() > 0 else float("inf")
            raise ValueError(
                "expected principal moments that satisfy the triangle inequality strictly (I1 + I2 − I3 at "
                f"least {INERTIA_MARGIN:g} × I3; a flat lamina makes the mass matrix singular), found principal "
                f"moments {shown} (the axes' inertia J = ½ tr(I) E − I has condition number {condition:.3g})"
            )
        return value

    def point(self, name: str) -> list[float]:
        p = self.points[name]
        return p.xyz() if isinstance(p, PolarPoint) else list(p)


class Anchor(_Strict):
    name: Name
    position: Position
    follows_path: list[Literal["x", "y", "z"]] = []  # axes along which it moves with the path


class Winch(_Strict):
    reflected_inertia: REFLECTED_INERTIA.field()  # kg, drum inertia seen by the cable length coordinate
    # m, the longest the cable can be paid out to: what its drum holds. Both plants stop a run that reaches it (a
    # DrumCapacityError) and the MJCF's drum ends there. Absent: the nominal length + DRUM_RESERVE_M
    # (acroboter.model.physical.drum_capacities).
    capacity: Length | None = None


class Cable(_Strict):
    name: Name
    ends: Annotated[list[str], _exactly(2, "2 ends ['anchor' or 'body.point', 'body.point']")]
    length: Length | None = None
    winch: Winch | None = None


# A limit may be infinite (TOML inf / -inf: unbounded on that side), never NaN.
Limit = LIMIT.field()


class _ActuatorBase(_Strict):
    name: Name
    # Generalized force per unit input (a motor constant, or -1 for a reversed mounting); never 0.
    gain: GAIN.field() = 1.0
    # [min, max] of the input in its own unit (N, N·m); default: see default_limits().
    limits: Annotated[list[Limit], _exactly(2, "2 numbers [min, max]")] | None = None
    # The value the tension distribution pulls an input towards where the task leaves it free (the
    # internal forces of redundant actuation); default: the middle of finite limits (see preferred_value).
    preferred: PREFERRED.field() | None = None

    @field_validator("limits")
    @classmethod
    def _limits_ordered(cls, value: list[float] | None) -> list[float] | None:
        if value is None:
            return value
        low, high = value
        if math.isnan(low) or math.isnan(high):
            raise ValueError(f"expected numbers or ±inf as [min, max], found {value}")
        if not low < high:
            raise ValueError(f"expected min < max, found min = {low:g} and max = {high:g}")
        if low == math.inf or high == -math.inf:
            raise ValueError(f"expected a finite min or max on the side it bounds, found {value}")
        return value

    def default_limits(self) -> tuple[float, float]:
        return (-math.inf, math.inf)

    def resolved_limits(self) -> tuple[float, float]:
        """[min, max] in the input's unit: the spec's, or the kind's default."""
        return tuple(self.limits) if self.limits is not None else self.default_limits()

    def preferred_value(self) -> float:
        """The spec's preferred value, else the middle of two finite limits, the finite one, or 0."""
        if self.preferred is not None:
            return self.preferred
        low, high = self.resolved_limits()
        if math.isfinite(low) and math.isfinite(high):
            return 0.5 * (low + high)
        return low if math.isfinite(low) else (high if math.isfinite(high) else 0.0)


class WinchTension(_ActuatorBase):
    kind: Literal["winch_tension"]
    cable: str

    def default_limits(self) -> tuple[float, float]:
        # A cable pulls and never pushes: the tension gain·u stays >= 0.
        return (0.0, math.inf) if self.gain > 0 else (-math.inf, 0.0)


class BodyTorque(_ActuatorBase):
    kind: Literal["body_torque"]
    body: str
    axis: Literal["u", "v", "w"]


class BodyThrust(_ActuatorBase):
    kind: Literal["body_thrust"]
    body: str
    axis: Literal["u", "v", "w"]
    point: Position = [0.0, 0.0, 0.0]  # where the force acts, body coordinates


Actuator = Annotated[WinchTension | BodyTorque | BodyThrust, Field(discriminator="kind")]


class PositionTask(_Strict):
    kind: Literal["position"]
    body: str
    point: Position = [0.0, 0.0, 0.0]


class YawTask(_Strict):
    kind: Literal["yaw"]
    body: str
    axis: Literal["u", "v"]


class LevelTask(_Strict):
    kind: Literal["level"]
    body: str
    axis: Literal["u", "v", "w"]


ServoConstraint = Annotated[PositionTask | YawTask | LevelTask, Field(discriminator="kind")]


def _kinds(*classes: type[BaseModel]) -> tuple[str, ...]:
    return tuple(get_args(c.model_fields["kind"].annotation)[0] for c in classes)


ACTUATOR_KINDS = _kinds(WinchTension, BodyTorque, BodyThrust)
TASK_KINDS = _kinds(PositionTask, YawTask, LevelTask)


class PathSpec(_Strict):
    waypoints: Annotated[list[Position], Field(min_length=2)]
    mean_speed: MEAN_SPEED.field()  # m/s
    yaw_deg: PATH_YAW.field() = 0.0


# The controller's tables: the parameters declared in acroboter.model.controller_parameters (their ranges, defaults,
# order) plus the fields that are not a controller parameter.
Penalty = create_model(
    "Penalty", __base__=_Strict, __module__=__name__,
    iterations=(Annotated[list[ITERATIONS.field()], Field(min_length=1)], [3, 4, 5]),
    **table_fields("controller.penalty"),
)
# The task's components, most important first: kept in this order while inputs are held at their limits (absent:
# horizontal, level, height, yaw, those the task has); each component of the task once.
Underactuation = create_model(
    "Underactuation", __base__=_Strict, __module__=__name__,
    priority=(list[Literal[TASK_COMPONENTS]] | None, None),
    **table_fields("controller.underactuation"),
)
Controller = create_model(
    "Controller", __base__=_Strict, __module__=__name__,
    rate_hz=(RATE.field(), ...),
    penalty=(Penalty, ...),
    underactuation=(Underactuation, Field(default_factory=Underactuation)),
    **table_fields("controller"),
)


def integral_gain_problem(kp: float, kd: float, ki: float) -> str | None:
    """Why ki does not go with kp, kd (None if it does): the servo error dynamics with integral action,
    s³ + 2k_D s² + k_P² s + k_I, are stable iff k_I < 2 k_D k_P² (Routh–Hurwitz; ki ≥ 0 checked apart; ki = 0 is
    the PD law, whatever kp² rounds to)."""
    bound = 2.0 * kd * kp**2
    if ki > 0 and ki >= bound:
        return (f"expected ki below 2·kd·kp² = {bound:g} 1/s³ (Routh–Hurwitz: the servo error dynamics "
                f"s³ + 2kd s² + kp² s + ki are unstable otherwise), found {ki:g}")
    return None


class Simulation(_Strict):
    step: STEP.field()
    baumgarte_zeta: BAUMGARTE_ZETA.field()
    baumgarte_omega: BAUMGARTE_OMEGA.field()


# Measurement instead of state (docs/sensing.md): which coordinates the controller's sensors measure.
MAX_SENSING_DELAY = DELAY.high  # control periods
SENSING_VECTORS = ("r", "u", "v", "w")


class SensingGroup(_Strict):
    name: Name
    # "<body>" (r, u, v, w), "<body>.<r|u|v|w>", "<body>.<r|u|v|w>_<x|y|z>", "<winch cable>.length"
    coordinates: Annotated[list[str], Field(min_length=1)]
    noise: NOISE.field() = 0.0  # standard deviation of the Gaussian noise, m or unitless
    quantization: QUANTIZATION.field() | None = None  # step of the quantiser, m or unitless; absent: no quantisation


class Sensing(_Strict):
    groups: Annotated[list[SensingGroup], Field(min_length=1)]
    delay_periods: DELAY.field() = 0  # whole control periods
    seed: SEED.field() = 0
    velocity_filter_s: VELOCITY_FILTER.field() = 0.02  # time constant of the velocity estimate, s
    projection_iterations: PROJECTION_ITERATIONS.field() = 3  # Gauss–Newton steps onto φ(q) = 0
    # Carry the delayed estimate forward to the control instant with the commanded accelerations.
    predict_delay: bool = True
    # The sample checks (docs/sensing.md, "Bad samples"): how far a sample may lie from its prediction, and how
    # long the estimator coasts on its prediction through rejected samples.
    max_speed: MAX_SPEED.field() = 1.0  # m/s
    max_axis_rate: MAX_AXIS_RATE.field() = 3.0  # 1/s
    max_coast_periods: MAX_COAST.field() = 10  # control periods


def sensing_coordinates(spec: Spec, selector: str) -> list[str] | None:
    """The coordinate names (acroboter.model.layout's) a sensing selector stands for; None if it names none."""
    bodies = {b.name for b in spec.bodies}
    winches = {c.name for c in spec.cables if c.winch is not None}
    head, _, tail = selector.partition(".")
    if head in bodies:
        if not tail:
            return [f"{head}.{vec}_{c}" for vec in SENSING_VECTORS for c in "xyz"]
        if tail in SENSING_VECTORS:
            return [f"{head}.{tail}_{c}" for c in "xyz"]
        if len(tail) == 3 and tail[0] in SENSING_VECTORS and tail[1:] in ("_x", "_y", "_z"):
            return [f"{head}.{tail}"]
        return None
    if head in winches and tail == "length":
        return [selector]
    return None


class Spec(_Strict):
    name: Name
    description: str = ""
    gravity: Annotated[list[GRAVITY.field()], _exactly(3, "3 numbers [x, y, z]")]
    anchors: list[Anchor] = []
    bodies: Annotated[list[Body], Field(min_length=1)]
    cables: list[Cable] = []
    actuators: Annotated[list[Actuator], Field(min_length=1)]
    task: Annotated[list[ServoConstraint], Field(min_length=1)]
    path: PathSpec
    controller: Controller
    simulation: Simulation
    sensing: Sensing | None = None  # absent: the controller reads the plant's state

    # --- what the generated code depends on -------------------------------------------------
    def model_dict(self) -> dict:
        """The part of the spec that the generated C depends on (path, gains, rates are run-time)."""
        return self.model_dump(
            mode="json", include={"name", "gravity", "anchors", "bodies", "cables", "actuators", "task"},
            exclude={"actuators": {"__all__": {"limits", "preferred"}}},  # read at run time
        )

    def model_hash(self) -> str:
        canonical = json.dumps(self.model_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()

    # --- lookups ------------------------------------------------------------------------------
    def body(self, name: str) -> Body:
        return next(b for b in self.bodies if b.name == name)

    def anchor(self, name: str) -> Anchor:
        return next(a for a in self.anchors if a.name == name)

    def input_limits(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(min, max, preferred) per input, in the spec's actuator order."""
        limits = np.array([a.resolved_limits() for a in self.actuators], dtype=float).reshape(-1, 2)
        preferred = np.array([a.preferred_value() for a in self.actuators], dtype=float)
        return limits[:, 0].copy(), limits[:, 1].copy(), preferred
