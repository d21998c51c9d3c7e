"""The controller's parameters, each declared once: name, spec key, unit and range (or its choices), default,
help, and whether it is a slot of the generated functions' run-time vector p.

Everything else is derived from `PARAMETERS`, so adding a gain is one edit here:

- the spec's fields: `table_fields` gives pydantic the fields of [controller], [controller.penalty] and
  [controller.underactuation] (acroboter.model.schema);
- the settings a controller runs with: `acroboter.model.settings.Gains`, a dataclass of every declared name;
- the generated C's parameter layout: `RUNTIME_NAMES` are the scalar slots of p in declaration order, then z, one
  per servo-constraint (`runtime_names`, `runtime_view`, `runtime_vector`: the only code that indexes p);
- the command lines' options (`flag`, `option_help`: acroboter.cli.entry.add_parameter_options) and the library's
  keyword overrides (`OVERRIDES`, `Crane.gains`);
- the validation of an override (`check_override`; the checks across gains, the sampled servo law and
  Routh–Hurwitz, are acroboter.model.settings.resolve_gains), whose message names the parameter as the user gave it.

The slot order is the generated C's: a runtime parameter added after the last runtime one keeps every existing
slot where it was.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .ranges import (
    ALPHA_GEOMETRIC,
    ALPHA_SERVO,
    DWELL,
    KAPPA,
    KD,
    KI,
    KP,
    MU,
    OMEGA,
    RELEASE_MARGIN,
    Range,
)

RECOVERIES = ("projected", "kinetic", "eq12", "eq13", "eq15", "kappa")
# How a controller meets an input limit (docs/saturation.md): the bounded least squares, or the saturated input
# fixed at its limit and the task reduced by priority (Zelei, Bencsik, Stépán 2017).
SATURATIONS = ("qp", "underactuation")

REQUIRED = object()  # a parameter the spec must give (no default)


@dataclass(frozen=True)
class ControllerParameter:
    """One controller parameter. `range` for a number, `choices` for a word; `runtime`: a slot of the generated
    functions' p (a number the compiled step reads at run time, not a constant folded into it); `option`: a keyword
    override of `Crane.gains` and an option of `acroboter run` / `export-step`; `exported`: also an option of
    `export-step`; `key`: the spec's key when it differs from `name`."""

    name: str
    table: str
    help: str
    range: Range | None = None
    choices: tuple[str, ...] = ()
    default: Any = REQUIRED
    runtime: bool = False
    option: bool = True
    exported: bool = True
    key: str = ""

    @property
    def flag(self) -> str:
        """The command lines' option: --alpha-geometric."""
        return "--" + self.name.replace("_", "-")

    @property
    def spec_field(self) -> str:
        """Where the spec gives it: controller.penalty.alpha_geometric."""
        return f"{self.table}.{self.key or self.name}"

    def read(self, spec) -> Any:
        """The spec's value (its default when the spec leaves it out, which the schema fills in)."""
        value = spec
        for part in self.spec_field.split("."):
            value = getattr(value, part)
        return value

    def problem(self, value: Any) -> str | None:
        """Why `value` is not one this parameter takes, in the ranges' words; None when it is."""
        if self.choices:
            return None if value in self.choices else f"expected one of {', '.join(self.choices)}, found {value!r}"
        return self.range.problem(value)

    def option_help(self) -> str:
        """The help of its command-line option: what it is, its range (argparse shows the choices), the default."""
        allowed = f"; {self.range.text()}" if self.range is not None else ""
        return f"{self.help}{allowed} (default: the spec's {self.spec_field})"

    def field(self):
        """(annotation, default) of its pydantic field in the spec's schema."""
        annotation = self.range.field() if self.range is not None else Literal[self.choices]
        return (annotation, ...) if self.default is REQUIRED else (annotation, self.default)


PARAMETERS: tuple[ControllerParameter, ...] = (
    ControllerParameter("kp", "controller", "servo gain k_P of the servo error dynamics ë + 2k_D ė + k_P² e = 0; "
                        "sampled at rate_hz it needs kp²/(4·rate_hz) < kd < rate_hz", KP, runtime=True),
    ControllerParameter("kd", "controller", "servo gain k_D, as kp", KD, runtime=True),
    ControllerParameter("alpha_geometric", "controller.penalty", "α̃, the penalty number of the geometric "
                        "constraints", ALPHA_GEOMETRIC, runtime=True),
    ControllerParameter("alpha_servo", "controller.penalty", "α̂, the penalty number of the servo-constraints",
                        ALPHA_SERVO, runtime=True),
    ControllerParameter("omega", "controller.penalty", "Ω of the constraint penalty's stabilisation", OMEGA,
                        runtime=True),
    ControllerParameter("mu", "controller.penalty", "μ of the constraint penalty's stabilisation", MU, runtime=True),
    ControllerParameter("ki", "controller", "integral gain k_I of the servo error dynamics, below 2·kd·kp²; 0: the "
                        "PD law (docs/integral_action.md)", KI, default=0.0, runtime=True),
    ControllerParameter("recovery", "controller.penalty", "input recovery of the penalty methods: projected (the "
                        "servo accelerations of the ideal servo force, exact where MLM is regular), kinetic (the whole "
                        "acceleration in the M⁻¹ metric, the default until 2026-12-06), or the paper's eq12, eq13, "
                        "eq15, kappa",
                        choices=RECOVERIES, default="projected"),
    ControllerParameter("kappa", "controller.penalty", "κ of the 'kappa' recovery's blend", KAPPA, default=0.5),
    ControllerParameter("saturation", "controller", "how a controller meets an input limit: qp (the bounded least "
                        "squares) or underactuation (the saturated input held at its limit, the task reduced by the "
                        "spec's [controller.underactuation] priority; docs/saturation.md)", choices=SATURATIONS,
                        default="qp", exported=False),
    ControllerParameter("dwell", "controller.underactuation", "saturation as underactuation: how long the full "
                        "task's input stays within its limits before the full task returns", DWELL, default=0.1,
                        option=False, exported=False),
    ControllerParameter("release_margin", "controller.underactuation", "saturation as underactuation: how far inside "
                        "each limit the full task's input must be before the full task returns", RELEASE_MARGIN,
                        default=0.001, option=False, exported=False, key="margin"),
)

BY_NAME = {p.name: p for p in PARAMETERS}
OVERRIDES = tuple(p.name for p in PARAMETERS if p.option)  # Crane.gains' keywords, run's options
RUNTIME_NAMES = tuple(p.name for p in PARAMETERS if p.runtime)  # p's scalar slots, in this order, then z


def parameter(name: str) -> ControllerParameter:
    return BY_NAME[name]


def table_fields(table: str) -> dict[str, tuple]:
    """The schema's fields of one spec table, in declaration order: {key: (annotation, default)}."""
    return {p.key or p.name: p.field() for p in PARAMETERS if p.table == table}


def check_override(name: str, value: Any) -> str | None:
    """Why `value` cannot override `name`; None when it can (None as a value: no override)."""
    return None if value is None else BY_NAME[name].problem(value)


# --- the run-time vector p of the generated functions (the only code that indexes it) --------------------------

def runtime_size(servo_rows: int) -> int:
    """len(p): the runtime scalars, then the integral z of each servo-constraint."""
    return len(RUNTIME_NAMES) + servo_rows


def runtime_names(servo_constraints: list[str]) -> list[str]:
    """p's entries by name, as the manifest records them."""
    return [*RUNTIME_NAMES, *(f"z[{name}]" for name in servo_constraints)]


@dataclass(frozen=True)
class RuntimeView:
    """p's entries by name (CasADi symbols or numbers): `scalars[name]` and the integral `z`."""

    scalars: dict[str, Any]
    z: Any

    def __getattr__(self, name: str):
        try:
            return self.__dict__["scalars"][name]
        except KeyError:
            raise AttributeError(name) from None


def runtime_view(p, servo_rows: int) -> RuntimeView:
    """p (a CasADi vector or a numpy array) read by name."""
    scalars = {name: p[i] for i, name in enumerate(RUNTIME_NAMES)}
    start = len(RUNTIME_NAMES)
    return RuntimeView(scalars, p[start : start + servo_rows])


def runtime_vector(settings, servo_rows: int) -> np.ndarray:
    """p for `settings` (anything with the runtime names as attributes), z zero: the controller writes it each
    step."""
    return np.concatenate([[float(getattr(settings, name)) for name in RUNTIME_NAMES], np.zeros(servo_rows)])


def integral_slice(servo_rows: int) -> slice:
    """Where z sits in p: a controller writes its integral there."""
    return slice(len(RUNTIME_NAMES), len(RUNTIME_NAMES) + servo_rows)
