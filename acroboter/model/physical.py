"""The crane's physical parameters by name: what a plant may have other than the controller's model.

The controller's generated functions fold the spec's numbers in as constants; the plant's
(`plant_step`, `plant_terms`, `plant_energy`) take them as a run-time input vector, in the order
of `parameter_names(spec)`, so that one compiled library simulates any sample of them. Names follow
the spec's own fields:

    gravity.x, gravity.y, gravity.z               m/s²
    <body>.mass                                   kg
    <body>.inertia.xx, <body>.inertia.yy, ...zz   kg·m², about the centre of mass in body axes
    <body>.inertia.xy, .xz, .yz                   only where the spec's is nonzero (one name sets both
                                                  symmetric entries): a product of inertia that is zero
                                                  in the spec stays a structural zero of M, which keeps
                                                  the plant's M⁻¹ block-diagonal and cheap
    <body>.damping.translational, .rotational     N·s/m, N·m·s
    <body>.points.<point>.x, .y, .z               m, in body axes (a polar point too: its x, y, z)
    <cable>.length                                m, a fixed-length cable
    <cable>.winch.reflected_inertia               kg, a winch cable's drum

A body's centre of mass is its frame's origin (natural coordinates), so a centre-of-mass offset
δ in the plant is its points moved by −δ (`SU.points.b1.z` etc.). What stays the controller's:
the tracked point of the task, the thrusters' points and every actuator gain (they define what
the controller measures and commands, not the crane it acts on).
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping

import numpy as np

from .spec import Spec, SpecError, parse_spec

COMPONENTS = ("x", "y", "z")
# Cable a drum holds beyond the nominal length (m) when the spec gives no `winch.capacity`.
DRUM_RESERVE_M = 10.0
# A run stops when a cable is paid out to within this of its drum's capacity (m): both plants, the same event.
DRUM_END_M = 1e-3
INERTIA_ENTRIES = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


class PlantParameterError(ValueError):
    """A plant parameter that is not one of the spec's, or a value the spec would not accept."""


def _inertia_names(body) -> list[str]:
    return [key for key, (a, b) in INERTIA_ENTRIES.items() if a == b or body.inertia[a][b] != 0.0]


def parameter_names(spec: Spec) -> list[str]:
    """Every physical parameter of the spec, in the order of the plant functions' input vector."""
    names = [f"gravity.{c}" for c in COMPONENTS]
    for body in spec.bodies:
        names.append(f"{body.name}.mass")
        names += [f"{body.name}.inertia.{key}" for key in _inertia_names(body)]
        names += [f"{body.name}.damping.translational", f"{body.name}.damping.rotational"]
        names += [f"{body.name}.points.{p}.{c}" for p in body.points for c in COMPONENTS]
    for cable in spec.cables:
        names.append(f"{cable.name}.length" if cable.winch is None else f"{cable.name}.winch.reflected_inertia")
    return names


def parameter_values(spec: Spec) -> np.ndarray:
    """The spec's own values of parameter_names(spec), in that order."""
    values = list(spec.gravity)
    for body in spec.bodies:
        values.append(body.mass)
        values += [body.inertia[a][b] for a, b in (INERTIA_ENTRIES[k] for k in _inertia_names(body))]
        values += [body.damping.translational, body.damping.rotational]
        for p in body.points:
            values += body.point(p)
    for cable in spec.cables:
        values.append(cable.length if cable.winch is None else cable.winch.reflected_inertia)
    return np.array(values, dtype=float)


def _set(data: dict, spec: Spec, name: str, value: float) -> None:
    """Write parameter `name` into `data` (the spec's model_dump) where the spec keeps it."""
    head, _, field = name.partition(".")
    if head == "gravity":
        data["gravity"][COMPONENTS.index(field)] = value
        return
    bodies = {b.name: i for i, b in enumerate(spec.bodies)}
    if head in bodies and not field.startswith(("length", "winch.")):
        body = data["bodies"][bodies[head]]
        if field == "mass":
            body["mass"] = value
        elif field.startswith("inertia."):
            a, b = INERTIA_ENTRIES[field.removeprefix("inertia.")]
            body["inertia"][a][b] = body["inertia"][b][a] = value
        elif field.startswith("damping."):
            body["damping"][field.removeprefix("damping.")] = value
        else:  # points.<point>.<component>: as [x, y, z], whatever form the spec gave it in
            point, component = field.removeprefix("points.").rsplit(".", 1)
            xyz = spec.body(head).point(point) if isinstance(body["points"][point], dict) else body["points"][point]
            xyz = list(xyz)
            xyz[COMPONENTS.index(component)] = value
            body["points"][point] = xyz
        return
    cable = next(i for i, c in enumerate(spec.cables) if c.name == head)
    if field == "length":
        data["cables"][cable]["length"] = value
    else:
        data["cables"][cable]["winch"]["reflected_inertia"] = value


def with_parameters(spec: Spec, overrides: Mapping[str, float]) -> Spec:
    """The spec with the given physical parameters replaced, checked as a spec is (positive masses,
    physical inertia tensors, positive lengths, ...). Raises PlantParameterError naming the parameter."""
    if not isinstance(overrides, Mapping):
        raise PlantParameterError(f"plant parameters: expected a mapping of names to numbers, found "
                                  f"{type(overrides).__name__}")
    names = parameter_names(spec)
    known = set(names)
    unknown = [name for name in overrides if name not in known]
    if unknown:
        zero_products = [n for n in unknown if isinstance(n, str) and n.rsplit(".", 1)[-1] in ("xy", "xz", "yz")
                         and n.rsplit(".", 2)[-2:-1] == ["inertia"]]
        hint = (" (a product of inertia that is zero in the spec is no plant parameter: give it a nonzero value "
                "in the spec to make it one)" if zero_products else "")
        raise PlantParameterError(
            f"unknown plant parameter(s) {', '.join(map(repr, unknown))} of spec '{spec.name}'{hint}; the "
            f"parameters are: {', '.join(names)}")
    if not overrides:
        return spec
    data = spec.model_dump()
    for name, value in overrides.items():  # each in its spec field's range (NaN, ±inf too): parse_spec says so
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise PlantParameterError(f"plant parameter {name}: expected a number, found {value!r}")
        _set(data, spec, name, float(value))
    try:
        return parse_spec(data, f"{spec.name} with plant parameters")
    except SpecError as err:
        given = ", ".join(f"{n}={v:g}" for n, v in overrides.items())
        problems = "; ".join(f"{path}: {msg}" for path, msg in err.problems)
        raise PlantParameterError(f"plant parameters {given} do not make a valid crane: {problems}") from None


def resolve(spec: Spec, overrides: Mapping[str, float] | None = None) -> np.ndarray:
    """The plant's parameter vector: the spec's values with `overrides` (name -> value) applied."""
    return parameter_values(with_parameters(spec, overrides or {}))


def drum_capacities(spec: Spec) -> dict[str, float]:
    """m, per winch cable: the longest it can be paid out to (`winch.capacity`, else its nominal length +
    DRUM_RESERVE_M). One property of the crane: the own plant, MuJoCo's and the MJCF all take it from here."""
    from .layout import build_layout, nominal_coordinates

    layout = build_layout(spec)
    q0 = nominal_coordinates(spec, layout)
    return {c.name: (c.winch.capacity if c.winch.capacity is not None
                     else float(q0[layout.winch_index[c.name]]) + DRUM_RESERVE_M)
            for c in spec.cables if c.winch is not None}
