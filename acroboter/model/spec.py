"""Model spec: parse a crane's TOML file, validate it, and report every problem by field path.

Field-level checks (types, unknown keys, positivity, inertia) are pydantic validators; checks that
need the whole spec (names referenced but not defined, duplicates, zero-length cables) run after
parsing. Both end up as one `SpecError` that lists each problem as `path: expected …, found …`.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
import types
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    field_validator,
)
from pydantic_core import PydanticCustomError

AXES = ("u", "v", "w")
# Caps that keep every command's work and memory bounded (checked here, once, before any work).
MAX_NAME_LENGTH = 64  # a name is a folder, a file name prefix and a C symbol prefix
MAX_ITERATIONS = 1000  # iterative penalty: far beyond where it stops improving (~10)
MAX_CONTROL_STEPS = 360_000  # 2 hours at 50 Hz: about 200 MB of records for the default crane
MAX_PLANT_SUBSTEPS = 10_000  # plant steps per control period
# A wide SI window for physical magnitudes: outside it a number is a unit mistake, not a crane.
MASS_RANGE = (1e-6, 1e6)  # kg
LENGTH_LIMIT = 1e4  # m, for positions, points and cable lengths
# J = ½ tr(I) E − I must stay well conditioned (it is the axes' part of M): I1 + I2 − I3 at least
# this fraction of I3 (a flat lamina, I1 + I2 = I3, makes M singular).
INERTIA_MARGIN = 1e-6
PATH_SIGNALS = ("x", "y", "z", "yaw")
RECOVERIES = ("projected", "eq12", "eq13", "eq15", "kappa")
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


Vec3 = Annotated[list[float], _exactly(3, "3 numbers [x, y, z]")]
Coordinate = Annotated[float, Field(ge=-LENGTH_LIMIT, le=LENGTH_LIMIT)]
Position = Annotated[list[Coordinate], _exactly(3, "3 numbers [x, y, z]")]  # m
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
Mass = Annotated[float, Field(ge=MASS_RANGE[0], le=MASS_RANGE[1])]
Length = Annotated[float, Field(gt=0, le=LENGTH_LIMIT)]
Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=MAX_NAME_LENGTH)]


class PolarPoint(_Strict):
    """A point in the body's xy-plane given by radius and angle, lifted by `height` along w."""

    radius: Annotated[float, Field(ge=0, le=LENGTH_LIMIT)]
    angle_deg: float
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
    translational: NonNegative = 0.0  # N·s/m on the centre-of-mass velocity
    rotational: NonNegative = 0.0  # N·m·s on the angular velocity


class Body(_Strict):
    name: Name
    mass: Mass
    inertia: Annotated[list[Vec3], _exactly(3, "a 3x3 matrix (3 rows of 3 numbers)")]
    initial_position: Position
    initial_yaw_deg: float = 0.0
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
    reflected_inertia: Positive  # kg, drum inertia seen by the cable length coordinate


class Cable(_Strict):
    name: Name
    ends: Annotated[list[str], _exactly(2, "2 ends ['anchor' or 'body.point', 'body.point']")]
    length: Length | None = None
    winch: Winch | None = None


# A limit may be infinite (TOML inf / -inf: unbounded on that side), never NaN.
Limit = Annotated[float, Field(allow_inf_nan=True)]


class _ActuatorBase(_Strict):
    name: Name
    # Generalized force per unit input (a motor constant, or -1 for a reversed mounting).
    gain: float = 1.0
    # [min, max] of the input in its own unit (N, N·m); default: see default_limits().
    limits: Annotated[list[Limit], _exactly(2, "2 numbers [min, max]")] | None = None
    # The value the tension distribution pulls an input towards where the task leaves it free (the
    # internal forces of redundant actuation); default: the middle of finite limits (see preferred_value).
    preferred: float | None = None

    @field_validator("gain")
    @classmethod
    def _gain_nonzero(cls, value: float) -> float:
        if value == 0:
            raise ValueError("expected a nonzero gain (a zero gain is no actuator), found 0")
        return value

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
    mean_speed: Annotated[float, Field(gt=0, le=LENGTH_LIMIT)]  # m/s
    yaw_deg: float = 0.0


class Penalty(_Strict):
    alpha_geometric: Positive
    alpha_servo: Positive
    omega: Positive
    mu: Positive
    iterations: Annotated[list[Annotated[int, Field(ge=1, le=MAX_ITERATIONS)]], Field(min_length=1)] = [3, 4, 5]
    recovery: Literal[RECOVERIES] = "projected"
    kappa: Annotated[float, Field(ge=0, le=1)] = 0.5



class Controller(_Strict):
    rate_hz: Positive
    kp: Positive
    kd: Positive
    # Integral action on the servo-constraints (docs/integral_action.md): 0 is the plain PD law.
    ki: NonNegative = 0.0
    penalty: Penalty


def integral_gain_problem(kp: float, kd: float, ki: float) -> str | None:
    """Why ki does not go with kp, kd (None if it does): the servo error dynamics with integral action,
    s³ + 2k_D s² + k_P² s + k_I, are stable iff k_I < 2 k_D k_P² (Routh–Hurwitz; ki ≥ 0 checked apart)."""
    bound = 2.0 * kd * kp**2
    if ki >= bound:
        return (f"expected ki below 2·kd·kp² = {bound:g} 1/s³ (Routh–Hurwitz: the servo error dynamics "
                f"s³ + 2kd s² + kp² s + ki are unstable otherwise), found {ki:g}")
    return None


class Simulation(_Strict):
    step: Positive
    baumgarte_zeta: Positive
    baumgarte_omega: Positive


# Measurement instead of state (docs/sensing.md): which coordinates the controller's sensors measure.
MAX_SENSING_DELAY = 1000  # control periods
SENSING_VECTORS = ("r", "u", "v", "w")


class SensingGroup(_Strict):
    name: Name
    # "<body>" (r, u, v, w), "<body>.<r|u|v|w>", "<body>.<r|u|v|w>_<x|y|z>", "<winch cable>.length"
    coordinates: Annotated[list[str], Field(min_length=1)]
    noise: NonNegative = 0.0  # standard deviation of the Gaussian noise, m or unitless
    quantization: Positive | None = None  # step of the quantiser, m or unitless; absent: no quantisation


class Sensing(_Strict):
    groups: Annotated[list[SensingGroup], Field(min_length=1)]
    delay_periods: Annotated[int, Field(ge=0, le=MAX_SENSING_DELAY)] = 0  # whole control periods
    seed: Annotated[int, Field(ge=0)] = 0
    velocity_filter_s: Annotated[float, Field(gt=0, le=100.0)] = 0.02  # time constant of the velocity estimate, s
    projection_iterations: Annotated[int, Field(ge=1, le=50)] = 3  # Gauss–Newton steps onto φ(q) = 0
    # Carry the delayed estimate forward to the control instant with the commanded accelerations.
    predict_delay: bool = True


def sensing_coordinates(spec: Spec, selector: str) -> list[str] | None:
    """The coordinate names (acroboter.layout's) a sensing selector stands for; None if it names none."""
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
    gravity: Annotated[list[Annotated[float, Field(ge=-1e3, le=1e3)]], _exactly(3, "3 numbers [x, y, z]")]
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


# --- checks that need the whole spec ---------------------------------------------------------


def body_rotation(yaw_deg: float) -> np.ndarray:
    """Rotation about the world z axis; its columns are the body axes u, v, w."""
    a = math.radians(yaw_deg)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _end_position(spec: Spec, end: str) -> np.ndarray:
    """World position of a cable end in the initial configuration."""
    if "." not in end:
        return np.array(spec.anchor(end).position)
    body_name, point_name = end.split(".", 1)
    body = spec.body(body_name)
    return np.array(body.initial_position) + body_rotation(body.initial_yaw_deg) @ np.array(body.point(point_name))


def _listing(names) -> str:
    names = list(dict.fromkeys(names))  # each once, in order
    return ", ".join(f"'{n}'" for n in names) if names else "none"


def _check_references(spec: Spec) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []

    # Names: bodies and anchors share one namespace (a cable end names either).
    for kind, named in (
        ("body or anchor", [(f"bodies[{i}].name", b.name) for i, b in enumerate(spec.bodies)]
         + [(f"anchors[{i}].name", a.name) for i, a in enumerate(spec.anchors)]),
        ("cable", [(f"cables[{i}].name", c.name) for i, c in enumerate(spec.cables)]),
        ("actuator", [(f"actuators[{i}].name", a.name) for i, a in enumerate(spec.actuators)]),
    ):
        first: dict[str, str] = {}
        for path, name in named:
            if name in first:
                problems.append(
                    (path, f"expected a unique {kind} name, found '{name}' again (first used at {first[name]})")
                )
            else:
                first[name] = path

    bodies: dict[str, Body] = {}
    for b in spec.bodies:
        bodies.setdefault(b.name, b)  # with duplicates, the first definition counts
    anchors = [a.name for a in spec.anchors]
    cables = {}
    for c in spec.cables:
        cables.setdefault(c.name, c)

    def body_ok(path: str, name: str) -> bool:
        if name not in bodies:
            problems.append((path, f"expected a defined body ({_listing(bodies)}), found '{name}'"))
            return False
        return True

    def end_ok(path: str, end: str) -> bool:
        if "." in end:
            body_name, point_name = end.split(".", 1)
            if not body_ok(path, body_name):
                return False
            if point_name not in bodies[body_name].points:
                known = _listing(bodies[body_name].points)
                problems.append(
                    (path, f"expected a point of body '{body_name}' (defined: {known}), found '{point_name}'")
                )
                return False
            return True
        if end not in anchors:
            problems.append(
                (path, f"expected a defined anchor ({_listing(anchors)}) or 'body.point', found '{end}'")
            )
            return False
        return True

    for i, cable in enumerate(spec.cables):
        base = f"cables[{i}] ({cable.name})"
        if (cable.length is None) == (cable.winch is None):
            problems.append(
                (base, "expected exactly one of 'length' (fixed cable) or 'winch' (length is a coordinate), "
                 f"found {'both' if cable.length is not None else 'neither'}")
            )
        if not all([end_ok(f"{base}.ends[{k}]", e) for k, e in enumerate(cable.ends)]):
            continue
        owners = [e.split(".", 1)[0] if "." in e else None for e in cable.ends]
        if owners == [None, None]:
            problems.append((f"{base}.ends", f"expected a cable that connects a body, found two anchors {cable.ends}"))
        elif owners[0] == owners[1]:
            problems.append(
                (f"{base}.ends", f"expected a cable between two different bodies (or an anchor and a body), "
                 f"found both ends on body '{owners[0]}': {cable.ends}")
            )
        elif cable.winch is not None:
            length0 = float(np.linalg.norm(_end_position(spec, cable.ends[0]) - _end_position(spec, cable.ends[1])))
            if length0 < 1e-9:
                problems.append(
                    (f"{base}.ends", f"expected a positive initial cable length, found {length0:.3g} m: "
                     f"{cable.ends[0]} and {cable.ends[1]} coincide in the initial configuration")
                )

    driven: dict[str, str] = {}
    for i, act in enumerate(spec.actuators):
        base = f"actuators[{i}] ({act.name})"
        if isinstance(act, WinchTension):
            winches = [c.name for c in spec.cables if c.winch is not None]
            if act.cable not in cables:
                problems.append(
                    (f"{base}.cable", f"expected a cable with a winch ({_listing(winches)}), "
                     f"found '{act.cable}', which is not a defined cable")
                )
            elif cables[act.cable].winch is None:
                problems.append(
                    (f"{base}.cable", f"expected a cable with a winch ({_listing(winches)}), "
                     f"found '{act.cable}', a fixed-length cable without a winch")
                )
            elif act.cable in driven:
                problems.append(
                    (f"{base}.cable", f"expected one winch_tension actuator per cable, found cable '{act.cable}' "
                     f"already driven by {driven[act.cable]}")
                )
            else:
                driven[act.cable] = base
        else:
            body_ok(f"{base}.body", act.body)

    for i, act in enumerate(spec.actuators):
        low, high = act.resolved_limits()
        if act.preferred is not None and not low <= act.preferred <= high:
            problems.append((f"actuators[{i}] ({act.name}).preferred",
                             f"expected a value within the limits [{low:g}, {high:g}], found {act.preferred:g}"))
        if isinstance(act, WinchTension) and (low < 0 if act.gain > 0 else high > 0):
            side = "min >= 0" if act.gain > 0 else "max <= 0 (the gain is negative)"
            problems.append((f"actuators[{i}] ({act.name}).limits",
                             f"expected limits that never make the cable push (a winch only pulls: {side}), "
                             f"found [{low:g}, {high:g}] with gain {act.gain:g}"))

    for i, task in enumerate(spec.task):
        body_ok(f"task[{i}] ({task.kind}).body", task.body)
    positions = [t for t in spec.task if isinstance(t, PositionTask)]
    if len(positions) != 1:
        given = ", ".join(t.kind for t in spec.task)
        problems.append(
            ("task", "expected exactly one servo-constraint of kind 'position' (the point the path moves), "
             f"found {len(positions)} (kinds given: {given})")
        )
    waypoints = np.array(spec.path.waypoints, dtype=float)
    if not (np.linalg.norm(np.diff(waypoints, axis=0), axis=1) > 0).any():
        problems.append(
            ("path.waypoints", "expected at least two distinct waypoints (the path moves the tracked point; a "
             f"yaw-only path is not supported), found {len(waypoints)} equal ones")
        )
    period = 1.0 / spec.controller.rate_hz
    substeps = round(period / spec.simulation.step)
    if substeps < 1 or not math.isclose(substeps * spec.simulation.step, period, rel_tol=1e-9):
        problems.append(("simulation.step", f"expected a plant step that divides the control period 1/rate_hz = "
                                            f"{period:g} s, found {spec.simulation.step:g} s"))
    elif substeps > MAX_PLANT_SUBSTEPS:
        problems.append(("simulation.step", f"expected at most {MAX_PLANT_SUBSTEPS} plant steps per control period, "
                                            f"found {substeps} ({spec.simulation.step:g} s in {period:g} s)"))
    lengths = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
    steps = lengths.sum() / spec.path.mean_speed * spec.controller.rate_hz
    if lengths.sum() > 0 and not steps >= 1:
        problems.append(("path.mean_speed", f"expected a path of at least one control step, found "
                                            f"{lengths.sum():g} m at {spec.path.mean_speed:g} m/s: "
                                            f"{steps:.3g} steps at {spec.controller.rate_hz:g} Hz; lower mean_speed"))
    if steps > MAX_CONTROL_STEPS:
        problems.append(("path", f"expected a path of at most {MAX_CONTROL_STEPS} control steps, found "
                                 f"{lengths.sum():g} m at {spec.path.mean_speed:g} m/s and "
                                 f"{spec.controller.rate_hz:g} Hz = {steps:.3g} steps: raise mean_speed or lower "
                                 "rate_hz"))
    if np.linalg.norm(spec.gravity) > 1e3:
        problems.append(("gravity", f"expected a gravity of at most 1000 m/s², found {np.linalg.norm(spec.gravity):g}"))
    for i, anchor in enumerate(spec.anchors):
        if len(set(anchor.follows_path)) != len(anchor.follows_path):
            problems.append((f"anchors[{i}].follows_path", f"expected each axis once, found {anchor.follows_path}"))
    c = spec.controller
    if (problem := integral_gain_problem(c.kp, c.kd, c.ki)) is not None:
        problems.append(("controller.ki", problem))
    if spec.sensing is not None:
        problems += sensing_problems(spec, spec.sensing)
    return problems


def sensing_problems(spec: Spec, sensing: Sensing) -> list[tuple[str, str]]:
    """Names in a sensing section: known selectors, each coordinate and each group name once."""
    problems: list[tuple[str, str]] = []
    seen: dict[str, str] = {}
    names: set[str] = set()
    for i, group in enumerate(sensing.groups):
        where = f"sensing.groups[{i}] ({group.name})"
        if group.name in names:
            problems.append((f"{where}.name", f"expected a group name used once, found '{group.name}' again"))
        names.add(group.name)
        for j, selector in enumerate(group.coordinates):
            found = sensing_coordinates(spec, selector)
            if found is None:
                problems.append((f"{where}.coordinates[{j}]", "expected '<body>', '<body>.r|u|v|w', "
                                 "'<body>.r_x' … or '<winch cable>.length' (bodies: "
                                 f"{_listing(b.name for b in spec.bodies)}; winch cables: "
                                 f"{_listing(c.name for c in spec.cables if c.winch is not None)}), "
                                 f"found '{selector}'"))
                continue
            for name in found:
                if name in seen:
                    problems.append((f"{where}.coordinates[{j}]", f"expected each coordinate in one group, found "
                                     f"{name} also in group '{seen[name]}'"))
                    break
                seen[name] = group.name
    return problems


# --- readable pydantic errors ------------------------------------------------------------------

_TOML_TYPES = {str: "a string", bool: "a boolean", int: "an integer", float: "a float", list: "an array",
               dict: "a table"}


def _found(value: Any) -> str:
    text = repr(value)
    if len(text) > 80:
        text = text[:77] + "..."
    kind = next((name for t, name in _TOML_TYPES.items() if type(value) is t), type(value).__name__)
    return f"{text} ({kind})"


def _clean_loc(loc: tuple, data: Any) -> list:
    """Drop union-branch tags from a pydantic location by walking the input along it."""
    parts, node = [], data
    for k, part in enumerate(loc):
        if isinstance(node, dict) and isinstance(part, str):
            if part in node:
                node = node[part]
            elif k < len(loc) - 1:
                continue  # a branch tag such as 'winch_tension' or 'polar'
            else:
                node = None  # the missing or unknown key itself
        elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            node = node[part]
        elif isinstance(node, list):
            continue  # a branch tag inside a list value ('xyz')
        parts.append(part)
    return parts


def _format_loc(parts: list, data: Any = None) -> str:
    loc = ""
    for k, part in enumerate(parts):
        loc += f"[{part}]" if isinstance(part, int) else (f".{part}" if loc else str(part))
        # name the actuator, as the cross-field checks do: actuators[0] (tension_1).limits
        if k == 1 and parts[0] == "actuators" and isinstance(part, int) and len(parts) > 2 and isinstance(data, dict):
            items = data.get(parts[0])
            item = items[part] if isinstance(items, list) and 0 <= part < len(items) else None
            if isinstance(item, dict) and isinstance(item.get("name"), str):
                loc += f" ({item['name']})"
    return loc or "(top level)"


def _strip(tp: Any, node: Any) -> Any:
    """The concrete type a value `node` is validated as: unwrap Annotated and pick the union member."""
    while True:
        origin = get_origin(tp)
        if origin is Annotated:
            tp = get_args(tp)[0]
        elif origin in (Union, types.UnionType):
            members = [_strip(m, node) for m in get_args(tp) if m is not type(None)]
            models = [m for m in members if isinstance(m, type) and issubclass(m, BaseModel)]
            if isinstance(node, dict) and models:
                tagged = [m for m in models if "kind" in m.model_fields
                          and node.get("kind") in get_args(m.model_fields["kind"].annotation)]
                return (tagged or models)[0]
            return members[0]
        else:
            return tp


def _known_keys(parts: list, data: Any) -> list[str]:
    """Field names of the table at `parts` (the location of an unknown key, without the key)."""
    tp, node = Spec, data
    try:
        for part in parts:
            tp = _strip(tp, node)
            if isinstance(tp, type) and issubclass(tp, BaseModel):
                tp = tp.model_fields[part].annotation
            else:  # list[...] or dict[str, ...]: the item type is the last argument
                tp = get_args(tp)[-1]
            node = node[part]
        tp = _strip(tp, node)
        return list(tp.model_fields) if isinstance(tp, type) and issubclass(tp, BaseModel) else []
    except (KeyError, IndexError, TypeError, AttributeError):
        return []


def _describe(e: dict, parts: list, data: Any) -> tuple[list, str]:
    """(location parts, 'expected …, found …') for one pydantic error."""
    kind, ctx, value = e["type"], e.get("ctx", {}), e.get("input")
    if kind == "missing":
        return parts, "expected this required field, found it missing"
    if kind == "extra_forbidden":
        known = _known_keys(parts[:-1], data)
        return parts, f"expected one of the known keys ({', '.join(known)}), found unknown key '{parts[-1]}'"
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        field = ctx.get("discriminator", "'kind'").strip("'")
        kinds = {"actuators": ACTUATOR_KINDS, "task": TASK_KINDS}.get(parts[0] if parts else "", ())
        expected = f"one of {_listing(kinds)}" if kinds else f"one of {ctx.get('expected_tags', '?')}"
        if kind == "union_tag_not_found" or not isinstance(value, dict) or field not in value:
            return [*parts, field], f"expected this required field ({expected}), found it missing"
        return [*parts, field], f"expected {expected}, found {_found(value[field])}"
    if kind == "literal_error":
        return parts, f"expected one of {ctx['expected']}, found {_found(value)}"
    if kind in ("float_type", "float_parsing", "int_type", "int_parsing", "int_from_float"):
        what = "an integer" if kind.startswith("int") else "a number"
        return parts, f"expected {what}, found {_found(value)}"
    if kind == "finite_number":
        return parts, f"expected a finite number, found {_found(value)}"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        bound = {"greater_than": ("greater than", "gt"), "greater_than_equal": ("at least", "ge"),
                 "less_than": ("less than", "lt"), "less_than_equal": ("at most", "le")}[kind]
        return parts, f"expected a number {bound[0]} {ctx[bound[1]]}, found {value!r}"
    if kind in ("string_type", "bool_type", "list_type", "dict_type", "model_type", "model_attributes_type"):
        what = {"string_type": "a string", "bool_type": "true or false", "list_type": "an array",
                "dict_type": "a table", "model_type": "a table", "model_attributes_type": "a table"}[kind]
        return parts, f"expected {what}, found {_found(value)}"
    if kind == "string_pattern_mismatch" and ctx.get("pattern") == NAME_PATTERN:
        return parts, ("expected a name of letters, digits and '_' that does not start with a digit, "
                       f"found {_found(value)}")
    if kind == "string_too_long":
        return parts, f"expected at most {ctx['max_length']} characters, found {len(value)}: {_found(value)}"
    if kind in ("too_short", "too_long"):
        limit = f"at least {ctx['min_length']}" if kind == "too_short" else f"at most {ctx['max_length']}"
        return parts, f"expected {limit} item(s), found {ctx.get('actual_length', len(value))}: {_found(value)}"
    if kind == "wrong_length":  # our message already says what was expected and how many were found
        return parts, f"{e['msg']}: {_found(value)}"
    if kind == "point_form":
        return parts, f"{e['msg']}, found {_found(value)}"
    if kind == "value_error":
        return parts, str(ctx.get("error", e["msg"]))
    msg = e["msg"]
    return parts, f"expected {msg[0].lower() + msg[1:]}, found {_found(value)}"


def _format_pydantic(err: ValidationError, data: Any) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []
    for e in err.errors(include_url=False):
        parts = _clean_loc(e["loc"], data)
        parts, text = _describe(e, parts, data)
        problem = (_format_loc(parts, data), text)
        if problem not in problems:
            problems.append(problem)
    return problems


def parse_spec(data: dict, source: str = "<spec>") -> Spec:
    """Validate a spec given as a dict; raise SpecError with every problem found."""
    try:
        spec = Spec.model_validate(data)
    except ValidationError as err:
        raise SpecError(source, _format_pydantic(err, data)) from None
    problems = _check_references(spec)
    if problems:
        raise SpecError(source, problems)
    return spec


def load_spec(path: str | Path) -> Spec:
    """Read and validate a TOML spec file."""
    path = Path(path)
    if not path.is_file():
        what = "a folder" if path.is_dir() else "nothing"
        raise SpecError(str(path), [("(file)", f"expected a readable TOML file, found {what} at this path")])
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as err:
        raise SpecError(str(path), [("(syntax)", f"expected valid TOML, found a syntax error: {err}")]) from None
    except (OSError, UnicodeDecodeError) as err:
        raise SpecError(str(path), [("(file)", f"expected a readable UTF-8 TOML file, found: {err}")]) from None
    return parse_spec(data, str(path))
