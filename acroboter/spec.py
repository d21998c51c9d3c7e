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
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

AXES = ("u", "v", "w")
PATH_SIGNALS = ("x", "y", "z", "yaw")
RECOVERIES = ("projected", "eq12", "eq13", "eq15", "kappa")


class SpecError(Exception):
    """A spec that cannot be used; `problems` lists (field path, message) pairs."""

    def __init__(self, source: str, problems: list[tuple[str, str]]):
        self.source = source
        self.problems = problems
        lines = [f"invalid model spec {source}:"]
        lines += [f"  {path}: {msg}" for path, msg in problems]
        super().__init__("\n".join(lines))


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
Name = Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]


class PolarPoint(_Strict):
    """A point in the body's xy-plane given by radius and angle, lifted by `height` along w."""

    radius: NonNegative
    angle_deg: float
    height: float = 0.0

    def xyz(self) -> list[float]:
        a = math.radians(self.angle_deg)
        return [self.radius * math.cos(a), self.radius * math.sin(a), self.height]


class Damping(_Strict):
    translational: NonNegative = 0.0  # N·s/m on the centre-of-mass velocity
    rotational: NonNegative = 0.0  # N·m·s on the angular velocity


class Body(_Strict):
    name: Name
    mass: Positive
    inertia: Annotated[list[Vec3], Field(min_length=3, max_length=3)]
    initial_position: Vec3
    initial_yaw_deg: float = 0.0
    damping: Damping = Damping()
    points: dict[Name, Vec3 | PolarPoint] = {}
    redundant_constraints: bool = False  # add w - u x v = 0 on top of the six orthonormality rows

    @field_validator("inertia")
    @classmethod
    def _inertia_is_physical(cls, value: list[list[float]]) -> list[list[float]]:
        i_g = np.array(value, dtype=float)
        if not np.allclose(i_g, i_g.T, rtol=0, atol=1e-12 * max(1.0, np.abs(i_g).max())):
            raise ValueError(f"expected a symmetric 3x3 inertia tensor, found {value}")
        moments = np.linalg.eigvalsh(i_g)
        if moments[0] <= 0:
            raise ValueError(
                f"expected a positive definite inertia tensor, found principal moments {moments.tolist()}"
            )
        if moments[0] + moments[1] < moments[2] * (1 - 1e-12):
            raise ValueError(
                "expected principal moments that satisfy the triangle inequality "
                f"(I1 + I2 >= I3), found {moments.tolist()}"
            )
        return value

    def point(self, name: str) -> list[float]:
        p = self.points[name]
        return p.xyz() if isinstance(p, PolarPoint) else list(p)


class Anchor(_Strict):
    name: Name
    position: Vec3
    follows_path: list[Literal["x", "y", "z"]] = []  # axes along which it moves with the path


class Winch(_Strict):
    reflected_inertia: Positive  # kg, drum inertia seen by the cable length coordinate


class Cable(_Strict):
    name: Name
    ends: Annotated[list[str], Field(min_length=2, max_length=2)]
    length: Positive | None = None
    winch: Winch | None = None


class WinchTension(_Strict):
    name: Name
    kind: Literal["winch_tension"]
    cable: str


class BodyTorque(_Strict):
    name: Name
    kind: Literal["body_torque"]
    body: str
    axis: Literal["u", "v", "w"]


class BodyThrust(_Strict):
    name: Name
    kind: Literal["body_thrust"]
    body: str
    axis: Literal["u", "v", "w"]
    point: Vec3 = [0.0, 0.0, 0.0]  # where the force acts, body coordinates


Actuator = Annotated[WinchTension | BodyTorque | BodyThrust, Field(discriminator="kind")]


class PositionTask(_Strict):
    kind: Literal["position"]
    body: str
    point: Vec3 = [0.0, 0.0, 0.0]


class YawTask(_Strict):
    kind: Literal["yaw"]
    body: str
    axis: Literal["u", "v"]


class LevelTask(_Strict):
    kind: Literal["level"]
    body: str
    axis: Literal["u", "v", "w"]


ServoConstraint = Annotated[PositionTask | YawTask | LevelTask, Field(discriminator="kind")]


class PathSpec(_Strict):
    waypoints: Annotated[list[Vec3], Field(min_length=2)]
    mean_speed: Positive
    yaw_deg: float = 0.0


class Penalty(_Strict):
    alpha_geometric: Positive
    alpha_servo: Positive
    omega: Positive
    mu: Positive
    iterations: Annotated[list[Annotated[int, Field(ge=1)]], Field(min_length=1)] = [3, 4, 5]
    recovery: Literal["projected", "eq12", "eq13", "eq15", "kappa"] = "projected"
    kappa: Annotated[float, Field(ge=0, le=1)] = 0.5


class Controller(_Strict):
    rate_hz: Positive
    kp: Positive
    kd: Positive
    penalty: Penalty


class Simulation(_Strict):
    step: Positive
    baumgarte_zeta: Positive
    baumgarte_omega: Positive


class Spec(_Strict):
    name: Name
    description: str = ""
    gravity: Vec3
    anchors: list[Anchor] = []
    bodies: Annotated[list[Body], Field(min_length=1)]
    cables: list[Cable] = []
    actuators: Annotated[list[Actuator], Field(min_length=1)]
    task: Annotated[list[ServoConstraint], Field(min_length=1)]
    path: PathSpec
    controller: Controller
    simulation: Simulation

    # --- what the generated code depends on -------------------------------------------------
    def model_dict(self) -> dict:
        """The part of the spec that the generated C depends on (path, gains, rates are run-time)."""
        return self.model_dump(
            mode="json", include={"name", "gravity", "anchors", "bodies", "cables", "actuators", "task"}
        )

    def model_hash(self) -> str:
        canonical = json.dumps(self.model_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()

    # --- lookups ------------------------------------------------------------------------------
    def body(self, name: str) -> Body:
        return next(b for b in self.bodies if b.name == name)

    def anchor(self, name: str) -> Anchor:
        return next(a for a in self.anchors if a.name == name)


def _duplicates(names: list[str]) -> list[str]:
    seen, dup = set(), []
    for n in names:
        if n in seen and n not in dup:
            dup.append(n)
        seen.add(n)
    return dup


def _end_position(spec: Spec, end: str) -> np.ndarray:
    """World position of a cable end in the initial configuration."""
    if "." not in end:
        return np.array(spec.anchor(end).position)
    body_name, point_name = end.split(".", 1)
    body = spec.body(body_name)
    yaw = math.radians(body.initial_yaw_deg)
    rot = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    return np.array(body.initial_position) + rot @ np.array(body.point(point_name))


def _check_references(spec: Spec) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []
    body_names = [b.name for b in spec.bodies]
    anchor_names = [a.name for a in spec.anchors]
    for kind, names in (
        ("body or anchor", body_names + anchor_names),
        ("cable", [c.name for c in spec.cables]),
        ("actuator", [a.name for a in spec.actuators]),
    ):
        for d in _duplicates(names):
            problems.append((f"name '{d}'", f"expected each {kind} name once, found it more than once"))
    bodies = {b.name: b for b in spec.bodies}
    anchors = set(anchor_names)

    def end_ok(path: str, end: str) -> bool:
        if "." in end:
            body_name, point_name = end.split(".", 1)
            if body_name not in bodies:
                problems.append((path, f"expected a defined body ({', '.join(bodies)}), found '{body_name}'"))
                return False
            if point_name not in bodies[body_name].points:
                known = ", ".join(bodies[body_name].points) or "none"
                problems.append(
                    (path, f"expected a point of body '{body_name}' (defined: {known}), found '{point_name}'")
                )
                return False
            return True
        if end not in anchors:
            problems.append(
                (path, f"expected an anchor name or 'body.point', found '{end}' (anchors: {', '.join(anchors) or 'none'})")
            )
            return False
        return True

    winch_cables = set()
    for i, cable in enumerate(spec.cables):
        base = f"cables[{i}] ({cable.name})"
        if (cable.length is None) == (cable.winch is None):
            problems.append(
                (base, "expected exactly one of 'length' (fixed cable) or 'winch' (length is a coordinate), "
                 f"found {'both' if cable.length is not None else 'neither'}")
            )
        if cable.winch is not None:
            winch_cables.add(cable.name)
        oks = [end_ok(f"{base}.ends[{k}]", e) for k, e in enumerate(cable.ends)]
        if all(oks):
            if cable.ends[0] == cable.ends[1] or all("." not in e for e in cable.ends):
                problems.append((f"{base}.ends", f"expected a cable that connects a body, found {cable.ends}"))
            elif cable.winch is not None:
                length0 = np.linalg.norm(_end_position(spec, cable.ends[0]) - _end_position(spec, cable.ends[1]))
                if length0 < 1e-9:
                    problems.append(
                        (f"{base}.ends", f"expected a positive initial cable length, found {length0:.3g} m "
                         "(both ends at the same place in the initial configuration)")
                    )

    for i, act in enumerate(spec.actuators):
        base = f"actuators[{i}] ({act.name})"
        if isinstance(act, WinchTension):
            if act.cable not in winch_cables:
                problems.append(
                    (f"{base}.cable", f"expected a cable with a winch ({', '.join(sorted(winch_cables)) or 'none'}), "
                     f"found '{act.cable}'")
                )
        elif act.body not in bodies:
            problems.append((f"{base}.body", f"expected a defined body ({', '.join(bodies)}), found '{act.body}'"))

    for i, task in enumerate(spec.task):
        if task.body not in bodies:
            problems.append(
                (f"task[{i}].body", f"expected a defined body ({', '.join(bodies)}), found '{task.body}'")
            )
    positions = [t for t in spec.task if isinstance(t, PositionTask)]
    if len(positions) != 1:
        problems.append(
            ("task", f"expected exactly one 'position' servo-constraint (the path's tracked point), found {len(positions)}")
        )
    for i, anchor in enumerate(spec.anchors):
        if _duplicates(list(anchor.follows_path)):
            problems.append((f"anchors[{i}].follows_path", f"expected each axis once, found {anchor.follows_path}"))
    return problems


def _format_pydantic(err: ValidationError) -> list[tuple[str, str]]:
    problems = []
    for e in err.errors(include_url=False):
        loc = ""
        for part in e["loc"]:
            if isinstance(part, int):
                loc += f"[{part}]"
            elif part in ("winch_tension", "body_torque", "body_thrust", "position", "yaw", "level",
                          "list[float]", "PolarPoint"):
                continue  # discriminator / union branch names are noise for the user
            else:
                loc += f".{part}" if loc else str(part)
        found = e.get("input")
        msg = e["msg"]
        if e["type"] == "missing":
            text = "expected this field, found it missing"
        elif e["type"] == "extra_forbidden":
            text = f"expected no such field (unknown key), found {found!r}"
        else:
            text = f"{msg[0].lower() + msg[1:]}; found {found!r}" if "found" not in msg else msg
            text = text.replace("Value error, ", "").replace("value error, ", "")
        problems.append((loc or "(top level)", text))
    return problems


def parse_spec(data: dict, source: str = "<spec>") -> Spec:
    """Validate a spec given as a dict; raise SpecError with every problem found."""
    try:
        spec = Spec.model_validate(data)
    except ValidationError as err:
        raise SpecError(source, _format_pydantic(err)) from None
    problems = _check_references(spec)
    if problems:
        raise SpecError(source, problems)
    return spec


def load_spec(path: str | Path) -> Spec:
    """Read and validate a TOML spec file."""
    path = Path(path)
    if not path.is_file():
        raise SpecError(str(path), [("(file)", "expected a readable TOML file, found nothing at this path")])
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise SpecError(str(path), [("(syntax)", f"expected valid TOML, found: {err}")]) from None
    return parse_spec(data, str(path))
