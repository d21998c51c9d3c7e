"""A range for every number: each number a spec or a command line takes has one, with its unit and the reason for
each bound, checked before any work, always in the same words:

    --kp: expected 0 < kp <= 1e4 (1/s), found 1e+308
    controller.kp: expected 0 < kp <= 1e4 (1/s), found 1e+200

`Range` is the one implementation: the spec's schema puts one on every numeric field (`Range.field()`, checked by
pydantic, reported by acroboter.model.spec_errors), the command lines on every numeric option
(acroboter.cli.entry.ranged: argparse's `type=`), the library's arguments call `Range.check`. A bound that another
number decides (the MuJoCo steps per control period, an animation's frames, a sensing delay within the run, the
servo gains a control rate can sample) is the same Range narrowed (`Range.narrowed`), so its message reads the same.
The constants below are every range; docs/spec.md and docs/errors.md list them with the reasons given here, and
tests/test_number_ranges.py checks that every numeric spec field and option has one and that both pages show it.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import Annotated, Any


def bound_text(value: float) -> str:
    """A bound as the docs write it: 0.002, 7200, 1e4, 1e-8, 2.5e12."""
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    if value.is_integer() and abs(value) < 1e4:
        return str(int(value))
    if abs(value) >= 1e4 or abs(value) < 1e-3:
        mantissa, exponent = f"{value:.6e}".split("e")
        return f"{mantissa.rstrip('0').rstrip('.')}e{int(exponent)}"
    return f"{value:.6g}"


def found_text(value: Any) -> str:
    """A value as found: floats as Python's %g writes them (1e+308, nan, -inf, -0), text quoted."""
    if isinstance(value, bool):
        return repr(value)
    if isinstance(value, numbers.Integral):
        text = str(int(value))
        return text if len(text) <= 24 else f"{text[:10]}…({len(text)} digits)"
    if isinstance(value, numbers.Real):
        return f"{float(value):g}"
    return repr(value)


@dataclass(frozen=True)
class Range:
    """The numbers a quantity may take: low..high (either end open or absent), its unit, and why.

    whole: only integers; magnitude: the bounds hold |x| (the sign is free); infinite: ±inf is allowed too
    (a limit's open side). NaN is never in a range."""

    name: str
    low: float | None = None
    high: float | None = None
    unit: str = ""
    why: str = ""
    low_open: bool = False
    high_open: bool = False
    whole: bool = False
    magnitude: bool = False
    infinite: bool = False

    def text(self) -> str:
        """'0 < kp <= 1e4 (1/s)': the range as the messages and the docs write it."""
        symbol = f"|{self.name}|" if self.magnitude else self.name
        low_op, high_op = ("<" if self.low_open else "<="), ("<" if self.high_open else "<=")
        if self.low is not None and self.high is not None:
            core = f"{bound_text(self.low)} {low_op} {symbol} {high_op} {bound_text(self.high)}"
        elif self.low is not None:
            core = f"{symbol} {'>' if self.low_open else '>='} {bound_text(self.low)}"
        else:
            core = f"{symbol} {high_op} {bound_text(self.high)}"
        if self.whole:
            core = f"a whole number {core}"
        if self.infinite:
            core += " or ±inf"
        return f"{core} ({self.unit})" if self.unit else core

    def contains(self, value: Any) -> bool:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        if self.whole:
            if not isinstance(value, numbers.Integral):
                return False
            x: float | int = int(value)
        else:
            x = float(value)
            if math.isnan(x):
                return False
            if math.isinf(x):
                return self.infinite
        if self.magnitude:
            x = abs(x)
        if self.low is not None and (x <= self.low if self.low_open else x < self.low):
            return False
        return not (self.high is not None and (x >= self.high if self.high_open else x > self.high))

    def problem(self, value: Any, note: str = "") -> str | None:
        """'expected 0 < kp <= 1e4 (1/s), found 1e+308' (and `note`, why a narrowed bound is where it is), or None
        for a value in the range."""
        if self.contains(value):
            return None
        found = repr(value) if self.whole and isinstance(value, float) else found_text(value)  # 3.0 is no whole 3
        return f"expected {self.text()}, found {found}" + (f" ({note})" if note else "")

    def check(self, value: Any, where: str | None = None, note: str = ""):
        """The value, or a RangeError (a ValueError) '<where>: expected …, found …'."""
        problem = self.problem(value, note)
        if problem is not None:
            raise RangeError(f"{where or self.name}: {problem}")
        return int(value) if self.whole else float(value)

    def parse(self, text: str, note: str = ""):
        """A command line's text as a number in the range; ValueError with the message (without the option's name,
        which argparse adds)."""
        text = str(text).strip()
        value: Any
        try:
            value = int(text) if self.whole else float(text)
        except ValueError:
            try:
                value = float(text)  # a whole number given as 1e3, or inf, nan: found as the number it is
            except ValueError:
                value = text
            if self.whole and isinstance(value, float) and value.is_integer() and abs(value) < 2**63:
                value = int(value)
        problem = self.problem(value, note)
        if problem is not None:
            raise ValueError(problem)
        return value

    def narrowed(self, *, low: float | None = None, high: float | None = None, low_open: bool | None = None,
                 high_open: bool | None = None) -> Range:
        """This range with a bound that another number decides moved inwards (never outwards)."""
        changes: dict[str, Any] = {}
        if low is not None and (self.low is None or low >= self.low):
            changes.update(low=low, low_open=self.low_open if low_open is None else low_open)
        if high is not None and (self.high is None or high <= self.high):
            changes.update(high=high, high_open=self.high_open if high_open is None else high_open)
        return dataclasses.replace(self, **changes)

    def field(self):
        """The pydantic type of a spec field in this range: NaN and ±inf reach the check (so the message names the
        range), the Range itself rides along in the metadata (tests/test_number_ranges.py walks the schema)."""
        from pydantic import AfterValidator, BeforeValidator, Field
        from pydantic_core import PydanticCustomError

        def validate(value):
            problem = self.problem(value)
            if problem is not None:
                raise PydanticCustomError("number_range", problem)
            return value

        if self.whole:  # a float (1.5, inf, nan, also 3.0) is refused in the range's words, not as "an integer"
            def not_a_float(value):
                return validate(value) if isinstance(value, float) else value

            return Annotated[int, BeforeValidator(not_a_float), AfterValidator(validate), self]
        return Annotated[float, Field(allow_inf_nan=True), AfterValidator(validate), self]


class RangeError(ValueError):
    """A number outside its range: '<where>: expected <range>, found <value>'."""


# --- the spec's numbers (acroboter.model.schema; docs/spec.md) --------------------------------------------------

MASS = Range("mass", 1e-6, 1e6, "kg", "a milligram to a thousand tonnes: outside, a unit slip (g for kg), not a crane")
COORDINATE = Range("coordinate", -1e4, 1e4, "m",
                   "positions, body points, waypoints: a 10 km window; beyond it a unit slip (mm for m)")
RADIUS = Range("radius", 0.0, 1e4, "m", "a polar point's distance from the w axis, within the coordinates' window")
ANGLE = Range("angle_deg", -360.0, 360.0, "deg", "a polar point's direction: one turn either way names every one")
GRAVITY = Range("gravity", -1e3, 1e3, "m/s²", "about 100 g per component (and |g| <= 1000): beyond, a unit slip")
INERTIA = Range("inertia", -1e12, 1e12, "kg·m²",
                "an entry of the tensor: the heaviest body (1e6 kg) 1 km from its axis; the principal moments must "
                "also be at least 1e-12 kg·m² (a milligram 1 mm from the axis), positive and meet the triangle "
                "inequality")
INITIAL_YAW = Range("initial_yaw_deg", -360.0, 360.0, "deg",
                    "the body's heading at the start (the yaw task's start heading): one turn either way names every "
                    "heading; further, the desired yaw keeps no digits of the path's turn (1e20° has none below 1e4°)")
DAMPING = Range("damping", 0.0, 1e6, "N·s/m or N·m·s",
                "a thousand tonnes stopped in a second; the plant's RK4 step must also integrate the damping's own "
                "rate: step · damping / mass (or the smallest principal moment) <= 2.6")
CABLE_LENGTH = Range("length", 1e-6, 1e4, "m",
                     "a fixed cable: below 1 µm its constraint |d|² − L² is round-off of the positions")
REFLECTED_INERTIA = Range("reflected_inertia", 1e-6, 1e6, "kg", "a winch drum's inertia seen by the cable: a mass")
GAIN = Range("gain", 1e-3, 1e3, "", magnitude=True,
             why="generalized force per unit input, either sign (−1: a reversed mounting): two inputs' columns of the "
                 "input matrix stay within 1e6 of each other, so the least-squares input recovery keeps its accuracy")
LIMIT = Range("limit", -1e9, 1e9, "N or N·m", infinite=True,
              why="an input's [min, max]: the heaviest body's weight at the strongest gravity (1e6 kg × 1e3 m/s²); inf "
                  "or -inf leaves that side open")
PREFERRED = Range("preferred", -1e9, 1e9, "N or N·m",
                  "where the distribution puts what the task leaves free: as limits")
MEAN_SPEED = Range("mean_speed", 1e-4, 100.0, "m/s",
                   "the path's mean speed: 0.1 mm/s (a metre in under 3 h) to 100 m/s; the path must also take 1 to "
                   "360,000 control steps")
PATH_YAW = Range("yaw_deg", -3600.0, 3600.0, "deg", "the path's total yaw turn: ten turns either way")
RATE = Range("rate_hz", 0.1, 1e4, "Hz",
             "the control rate: a period of 10 s to 100 µs (about six times the compiled step's 16 µs)")
KP = Range("kp", 0.0, 1e4, "1/s", low_open=True,
           why="servo error dynamics s² + 2kd s + kp²: kp², 2·kd·kp² stay finite; the law sampled at rate_hz must also "
               "stay stable: kp²·T/4 < kd < 1/T, T = 1/rate_hz (0.125 < kd < 50 for kp = 5 at 50 Hz)")
KD = Range("kd", 0.0, 1e4, "1/s", low_open=True, why="as kp: kp²·T/4 < kd < 1/T, T = 1/rate_hz")
KI = Range("ki", 0.0, 2e12, "1/s³",
           "integral action: 2·kd·kp² at the largest kp, kd; with kp, kd also ki < 2·kd·kp² (Routh–Hurwitz)")
ALPHA = Range("alpha", 1.0, 1e16, "",
              "a penalty number (α̃, α̂): an iteration of the iterative penalty method cuts the servo-constraints' miss "
              "by about α, so α <= 1 enforces nothing; 1e16 ≈ 1/eps, past which the Cholesky factor of "
              "A = M + α JᵀJ cannot exist (the default crane's fails from 1e15 with a clear error: the sweep)")
ALPHA_GEOMETRIC = dataclasses.replace(ALPHA, name="alpha_geometric")
ALPHA_SERVO = dataclasses.replace(ALPHA, name="alpha_servo")
OMEGA = Range("omega", 0.0, 1e4, "1/s", low_open=True, why="Ω of the constraint penalty: as kp, Ω² stays finite")
MU = Range("mu", 0.0, 1e3, "", low_open=True, why="μ of the constraint penalty, a damping ratio: 2μΩ stays finite")
ITERATIONS = Range("iterations", 1, 1000, "", whole=True,
                   why="iterative penalty: far beyond where it stops improving (about 10)")
KAPPA = Range("kappa", 0.0, 1.0, "", "the 'kappa' recovery's blend of two recoveries")
DWELL = Range("dwell", 0.0, 60.0, "s",
              "saturation as underactuation: how long the full task's input must stay within its limits before the "
              "full task returns (0: at once; a minute is longer than any saturation worth waiting out)")
RELEASE_MARGIN = Range("margin", 0.0, 0.5, "",
                       "saturation as underactuation: the full task's input must be inside each limit by this fraction "
                       "of the limit's magnitude before the full task returns (0.001 = 0.1 %)")
STEP = Range("step", 1e-8, 10.0, "s",
             "the plant's RK4 step: it divides the control period, at most 10,000 times (1e-8 s: 10,000 steps in the "
             "shortest period, 100 µs)")
BAUMGARTE_ZETA = Range("baumgarte_zeta", 0.0, 1e3, "", low_open=True, why="the plant's Baumgarte damping ratio")
BAUMGARTE_OMEGA = Range("baumgarte_omega", 0.0, 1e4, "1/s", low_open=True,
                        why="the plant's Baumgarte frequency: the fastest pole ω(ζ + √(ζ² − 1)) (ω for ζ < 1) "
                            "times the step must stay inside RK4's stability region, <= 2.6 (at least 2.61 in any "
                            "direction)")
NOISE = Range("noise", 0.0, 1.0, "m or unitless",
              "a sensing group's noise: the standard deviation of a position (m) or an axis' component (unitless, "
              "at most 1)")
QUANTIZATION = Range("quantization", 1e-12, 1.0, "m or unitless",
                     "a sensing group's quantisation step: above the round-off of a 1e4 m coordinate, at most an axis' "
                     "whole range")
DELAY = Range("delay_periods", 0, 1000, "control periods", whole=True,
              why="the measurement delay; it must also be shorter than the run (the path, or --duration)")
SEED = Range("seed", 0, 2**63 - 1, "", whole=True, why="a seed of numpy's generator: a TOML integer")
VELOCITY_FILTER = Range("velocity_filter_s", 0.0, 100.0, "s", low_open=True,
                        why="the velocity estimate's time constant")
PROJECTION_ITERATIONS = Range("projection_iterations", 1, 50, "", whole=True,
                              why="Gauss–Newton steps onto φ(q) = 0 (3 converge)")
MAX_SPEED = Range("max_speed", 0.0, 1e3, "m/s", low_open=True,
                  why="the fastest a measured position or cable length can move away from its prediction: a sample "
                      "further than max_speed × the control period (plus 10 noise σ and a quantisation step) is not "
                      "a motion of the crane and is rejected")
MAX_AXIS_RATE = Range("max_axis_rate", 0.0, 1e4, "1/s", low_open=True,
                      why="the same for a measured axis component (unitless): the crane's fastest rotation rate")
MAX_COAST = Range("max_coast_periods", 1, 1000, "control periods", whole=True,
                  why="rejected samples in a row the estimator coasts on its prediction before it declares the "
                      "estimate lost (the controller then holds its last good command)")

# --- numbers of the command lines only (acroboter.cli; docs/errors.md) --------------------------------------------

MARGIN = Range("margin", 0.0, 0.5, "", high_open=True,
               why="a retiming's margin: the fraction of each input's limit span kept free on each side (5 % = 0.05); "
                   "half the span would leave nothing (docs/planning.md)")
PLAN_SPEED = Range("max_speed", 0.0, 100.0, "m/s", low_open=True, why="a retiming's bound on the tracked point's speed")
PLAN_ACCEL = Range("max_accel", 0.0, 1000.0, "m/s²", low_open=True,
                   why="a retiming's bound on the tracked point's acceleration (about 100 g at most)")
PLAN_JERK = Range("max_jerk", 0.0, 1e5, "m/s³", low_open=True,
                  why="a retiming's bound on the tracked point's jerk (a smooth timing: σ̈ continuous)")
PLAN_TOLERANCE = Range("tolerance", 1e-7, 1.0, "m",
                       why="a plan's flown position error (0.1 µm to 1 m): the flights of every method stay within it")
PLAN_INTERVALS = Range("intervals", 4, 5000, "", whole=True,
                       why="the retiming's grid: intervals over the whole path (each edge gets at least 6)")
PLAN_WINDOW = Range("window", 0, 1000, "", whole=True,
                    why="the retiming's receding window: phases (edges) optimised together, 0 for the whole path in "
                        "one solve")
DURATION = Range("duration", 0.0, 1e6, "s", low_open=True,
                 why="simulated seconds; also 1 to 360,000 control steps of the spec's rate (checked with the spec)")
STUDY_DURATION = Range("duration", 0.0, 7200.0, "s", low_open=True,
                       why="a study's runs: at most 360,000 control steps at its cranes' 50 Hz, 2 h")
MUJOCO_TIMESTEP = Range("mujoco_timestep", 1e-8, 0.01, "s",
                        "MuJoCo's step: it divides the plant step, and makes at most 100,000 steps per control "
                        "period (2e-7 s at 50 Hz; 55 s of path are then 2.75e8 steps); above 10 ms the cables' "
                        "constraint time constant (two steps) is too soft to call them cables")
MAX_MUJOCO_STEPS_PER_PERIOD = 100_000
FUZZ_TIMESTEP = dataclasses.replace(MUJOCO_TIMESTEP, high=1e-3,
                                    why="as --mujoco-timestep of run; at most 1 ms, where MuJoCo still converges "
                                        "on the own plant")
TOLERANCE = Range("tolerance", 1.0, 1e6, "", low_open=True,
                  why="a run is good within this factor of MLM's error: above 1, at most a million")
WORKERS = Range("workers", 1, 64, "", whole=True, why="local worker processes")
WORKERS_OR_NONE = dataclasses.replace(WORKERS, low=0, why="local worker processes, 0: in this process")
CONNECT_TIMEOUT = Range("connect_timeout", 0.0, 3600.0, "s", low_open=True, why="waiting for a scheduler: an hour")
SAMPLES = Range("samples", 1, 10_000, "", whole=True, why="Monte Carlo samples: 10,000 × 5 methods × 2 runs")
RELATIVE_RANGE = Range("range", -0.9, 9.0, "fraction",
                       "a relative robustness range (masses, inertias, dampings): from a tenth to ten times the "
                       "model's value; beyond, another crane rather than a model error")
OFFSET_RANGE = Range("range", -1000.0, 1000.0, "mm",
                     "an absolute robustness range (points, cable lengths): a metre either way; a draw the spec "
                     "refuses (a negative length) is drawn again")
INTEGRAL_GAIN = dataclasses.replace(KI, low_open=True, why="the ki of the integral-action rows: positive, as ki")
REPEATS = Range("repeats", 1, 100, "", whole=True, why="passes over the scenario's states")
CASADI_STATES = Range("casadi_states", 1, 100_000, "", whole=True, why="states timed through casadi.Function")
MC_SAMPLES = Range("mc_samples", 0, 200, "", whole=True,
                   why="plants of the default robustness study whose runs the benchmark times (0: none)")
FUZZ_CASES = Range("cases", 1, 100_000, "", whole=True, why="open-loop experiments")
FUZZ_CRANES = Range("cranes", 1, 10_000, "", whole=True, why="generated cranes, each generated and compiled (~7 s)")
FUZZ_SEED = Range("seed", 0, 2**31, "", whole=True, why="seed of the first case (case i: seed + i)")
FUZZ_CRANE_SEED = Range("crane_seed", 0, 2**31, "", whole=True, why="the first generated crane's seed")
FPS = Range("fps", 0.01, 240.0, "frames/s", "the MP4's frame rate: from a frame per 100 s (a slide show)")
GIF_FPS = Range("gif_fps", 0.01, 50.0, "frames/s",
                "the GIF's frame rate: a GIF's delay is whole centiseconds, 2 (50 fps) to 65535 (a frame per 100 s "
                "is 10,000)")
SPEED = Range("speed", 1e-3, 1000.0, "run s per video s",
              "the video's speed; the frames it makes are also counted up front: at most 200,000 (the longest run, "
              "2 h, in real time at 25 fps)")
GIF_SPEED = dataclasses.replace(SPEED, name="gif_speed",
                                why="the GIF's speed; at most 200,000 frames, and at most 1 GB of them held (one byte "
                                    "a pixel) until the GIF is written")
WIDTH = Range("width", 64, 7680, "pixels", whole=True, why="the MP4's frame width (8K)")
HEIGHT = Range("height", 64, 4320, "pixels", whole=True, why="the MP4's frame height (8K)")
GIF_WIDTH = Range("gif_width", 64, 1920, "pixels", whole=True,
                  why="the GIF's width: the writer holds every frame (1920×1440: 2.8 MB a frame)")
MAX_FRAMES = 200_000
MAX_GIF_BYTES = 10**9


def frames_problem(duration: float, fps: float, speed: float, speed_range: Range, pixels: int | None = None
                   ) -> str | None:
    """Why an animation of `duration` run seconds at `fps` and `speed` makes too many frames (at most MAX_FRAMES;
    a GIF, whose writer holds every frame of `pixels` bytes, at most MAX_GIF_BYTES of them), found before any frame
    is drawn; None when it does not. The message is the speed's range narrowed to this run."""
    frames = math.floor(duration * fps / speed + 1e-9) + 1
    cap = MAX_FRAMES if pixels is None else min(MAX_FRAMES, MAX_GIF_BYTES // pixels)
    if frames <= cap:
        return None
    slowest = duration * fps / max(cap - 1, 1)
    held = "" if pixels is None else f", {frames * pixels / 1e9:.3g} GB held"
    need = (f"{frames:,} frames{held}; at most {cap:,} frames" + (f" ({MAX_GIF_BYTES / 1e9:g} GB of "
            f"{pixels:,}-byte frames)" if pixels is not None else "") + f" of this {duration:g} s run at {fps:g} fps")
    return speed_range.narrowed(low=slowest).problem(speed, need)


def mujoco_work_problem(timestep: float, control_period: float) -> str | None:
    """Why a MuJoCo step is too short for a control period (more than MAX_MUJOCO_STEPS_PER_PERIOD steps in it); None
    when it is not."""
    if timestep * MAX_MUJOCO_STEPS_PER_PERIOD >= control_period * (1 - 1e-12):
        return None
    low = control_period / MAX_MUJOCO_STEPS_PER_PERIOD
    note = (f"at most {MAX_MUJOCO_STEPS_PER_PERIOD:,} MuJoCo steps per control period of {control_period:g} s, "
            f"found {control_period / timestep:.3g}")
    return MUJOCO_TIMESTEP.narrowed(low=low).problem(timestep, note)


def delay_problem(delay: int, rate_hz: float, duration: float, what: str = "run") -> str | None:
    """Why a sensing delay of `delay` control periods is not shorter than a run of `duration` s; None if it is."""
    periods = round(duration * rate_hz)
    if delay < periods:
        return None
    note = f"a delay shorter than the {duration:g} s {what}: {periods} control periods at {rate_hz:g} Hz"
    return DELAY.narrowed(high=max(periods - 1, 0)).problem(delay, note)


def sampled_gain_problems(kp: float, kd: float, rate_hz: float, names: tuple[str, str] = ("controller.kp",
                                                                                          "controller.kd"),
                          given: tuple[bool, bool] = (False, True)) -> list[tuple[str, str]]:
    """The servo law ë = −2kd ė − kp² e sampled at rate_hz (the acceleration held over T = 1/rate_hz) is stable iff
    kd·T < 1 and kp²·T < 4·kd (Jury's test of its characteristic polynomial z² − (2 − 2kdT − kp²T²/2) z +
    1 − 2kdT + kp²T²/2): the problems as (where, text), none when it is. The problem names the gain the user gave
    (`given`: kp, kd), with the range that gain may take at the other one's value; a range that would be empty
    (kd past 1/T, or kp past 2/T) blames the gain that caused it."""
    period = 1.0 / rate_hz
    if kd * period < 1.0 and kp * kp * period < 4.0 * kd:
        return []
    note = f"the servo law sampled at rate_hz = {rate_hz:g} Hz is stable only for kp²·T/4 < kd < 1/T"
    kd_fits = kp * kp * period / 4.0 < 1.0 / period  # some kd works with this kp (kp < 2/T)
    kp_fits = kd * period < 1.0  # some kp works with this kd
    blame_kd = kd_fits and (not kp_fits or (given[1] and not given[0]))
    if blame_kd:
        window = KD.narrowed(low=kp * kp * period / 4.0, low_open=True, high=1.0 / period, high_open=True)
        also = f"; or kp below {math.sqrt(4.0 * kd / period):.4g}" if kp_fits else ""  # kd too small for kp
        return [(names[1], window.problem(kd, f"{note} (kp = {kp:g}){also}"))]
    if kp_fits:  # kp too large for this kd
        window = KP.narrowed(high=math.sqrt(4.0 * kd / period), high_open=True)
        return [(names[0], window.problem(kp, f"{note} (kd = {kd:g}: kp < √(4 kd/T))"))]
    window = KD.narrowed(high=1.0 / period, high_open=True)  # kd too large, and kp too for any kd
    return [(names[1], window.problem(kd, f"{note}; and kp below 2/T = {2.0 / period:g}"))]


RK4_RADIUS = 2.6  # RK4's stability region holds every λh of the left half-plane with |λh| <= 2.61


def baumgarte_problem(zeta: float, omega: float, step: float) -> str | None:
    """Why the plant's Baumgarte stabilisation φ̈ + 2ζω φ̇ + ω² φ = 0 is too fast for its RK4 step; None if it is not."""
    fastest = omega * (zeta + math.sqrt(zeta * zeta - 1.0)) if zeta >= 1.0 else omega
    if fastest * step <= RK4_RADIUS:
        return None
    scale = fastest / omega
    note = (f"the fastest Baumgarte pole {fastest:.4g} 1/s times the step {step:g} s is {fastest * step:.3g}, outside "
            f"RK4's stability region (<= {RK4_RADIUS:g})")
    return BAUMGARTE_OMEGA.narrowed(high=RK4_RADIUS / (step * scale)).problem(omega, note)


def damping_problem(damping: float, inertia: float, step: float, what: str) -> str | None:
    """Why a body's damping is too stiff for the plant's RK4 step (rate damping / `inertia`, the mass or the smallest
    principal moment); None when it is not."""
    if damping * step <= RK4_RADIUS * inertia:
        return None
    note = (f"its rate damping / {what} times the step {step:g} s is {damping * step / inertia:.3g}, outside RK4's "
            f"stability region (<= {RK4_RADIUS:g})")
    return DAMPING.narrowed(high=RK4_RADIUS * inertia / step).problem(damping, note)
