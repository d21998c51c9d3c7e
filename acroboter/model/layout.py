"""Index layout of a spec: where each body, cable length, constraint, input and signal lives.

Shared by the code generator and the numeric side so both agree on every index. Coordinates are
q = [q_body (12 each: r, u, v, w) ... | winch cable lengths ...].
Signals (the only way time enters the generated code) are
s = [position of each moving anchor (3 each) ... | x_d, y_d, z_d, yaw_d].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .spec import (
    PATH_SIGNALS,
    BodyThrust,
    LevelTask,
    PositionTask,
    Spec,
    WinchTension,
    YawTask,
    body_rotation,
)


@dataclass(frozen=True)
class Layout:
    coordinates: list[str]
    constraints: list[str]
    servo_constraints: list[str]
    inputs: list[str]
    signals: list[str]
    body_offset: dict[str, int] = field(default_factory=dict)
    winch_index: dict[str, int] = field(default_factory=dict)
    anchor_signal: dict[str, int] = field(default_factory=dict)  # moving anchor -> first signal index
    path_signal: int = 0  # index of x_d; y_d, z_d, yaw_d follow
    redundant_rows: tuple[int, ...] = ()  # constraint rows implied by the others (w = u × v)
    input_units: list[str] = field(default_factory=list)  # "N" or "N·m" per input

    @property
    def n(self) -> int:
        return len(self.coordinates)

    @property
    def m(self) -> int:
        return len(self.constraints)

    @property
    def k(self) -> int:
        """Number of servo-constraints (equals the number of inputs for a square task)."""
        return len(self.servo_constraints)

    @property
    def l(self) -> int:  # noqa: E743 - the paper's name for the number of inputs
        return len(self.inputs)

    @property
    def n_signals(self) -> int:
        return len(self.signals)


def build_layout(spec: Spec) -> Layout:
    coords: list[str] = []
    body_offset = {}
    for body in spec.bodies:
        body_offset[body.name] = len(coords)
        coords += [f"{body.name}.{vec}_{c}" for vec in ("r", "u", "v", "w") for c in "xyz"]
    winch_index = {}
    for cable in spec.cables:
        if cable.winch is not None:
            winch_index[cable.name] = len(coords)
            coords.append(f"{cable.name}.length")

    constraints = []
    redundant_rows: list[int] = []
    for body in spec.bodies:
        b = body.name
        constraints += [f"{b}: u.u-1", f"{b}: v.v-1", f"{b}: w.w-1", f"{b}: u.v", f"{b}: v.w", f"{b}: w.u"]
        if body.redundant_constraints:
            redundant_rows += range(len(constraints), len(constraints) + 3)
            constraints += [f"{b}: (w-u×v)_{c}" for c in "xyz"]
    constraints += [f"cable {c.name}" for c in spec.cables]

    servo = []
    for task in spec.task:
        if isinstance(task, PositionTask):
            servo += [f"{task.body} position {c}" for c in "xyz"]
        elif isinstance(task, YawTask):
            servo.append(f"{task.body} yaw via {task.axis}")
        elif isinstance(task, LevelTask):
            servo += [f"{task.body} level {task.axis}_{c}" for c in "xy"]

    inputs = [act.name for act in spec.actuators]
    input_units = ["N" if isinstance(act, (WinchTension, BodyThrust)) else "N·m" for act in spec.actuators]

    signals: list[str] = []
    anchor_signal = {}
    for anchor in spec.anchors:
        if anchor.follows_path:
            anchor_signal[anchor.name] = len(signals)
            signals += [f"{anchor.name}.{c}" for c in "xyz"]
    path_signal = len(signals)
    signals += [f"{s}_d" for s in PATH_SIGNALS]
    return Layout(coords, constraints, servo, inputs, signals, body_offset, winch_index, anchor_signal, path_signal,
                  tuple(redundant_rows), input_units)


def nominal_coordinates(spec: Spec, layout: Layout) -> np.ndarray:
    """q of the spec's initial configuration (bodies at initial_position, yawed, cables taut)."""
    q = np.zeros(layout.n)
    world_points = {}
    for body in spec.bodies:
        i = layout.body_offset[body.name]
        rot = body_rotation(body.initial_yaw_deg)
        q[i : i + 3] = body.initial_position
        q[i + 3 : i + 12] = rot.T.reshape(-1)  # u, v, w = columns of rot
        for p in body.points:
            world_points[f"{body.name}.{p}"] = np.array(body.initial_position) + rot @ np.array(body.point(p))
    for anchor in spec.anchors:
        world_points[anchor.name] = np.array(anchor.position)
    for cable in spec.cables:
        if cable.winch is not None:
            a, b = (world_points[e] for e in cable.ends)
            q[layout.winch_index[cable.name]] = np.linalg.norm(a - b)
    return q
