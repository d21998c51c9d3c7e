"""The hand-written part of the stateful exported controller (acroboter.codegen.controller_c): <name>.h and <name>.c,
rendered from acroboter/c/controller.h and controller.c (with estimator.c and path.c). The header's comment
is written here: everything a C developer needs to deploy the controller from the header alone (units and frames of
every argument, the measurement vector's layout as macros, the return codes and what u and the state hold after
each, the sample checks and their numbers, iteration counts, state size, stack, the libm symbols).
"""

from __future__ import annotations

import ctypes
import hashlib
import re
import textwrap

import casadi as ca

from ..model.c_templates import render
from ..model.sensing_layout import GATE_SIGMAS, PROJECTION_ACCEPT, PROJECTION_TOLERANCE
from .estimator_c import estimator_text
from .step_qp import QP_PLUGIN

# qrqp's default iteration limit (CasADi 3.x 'max_iter'): the bounded QP's worst case, where a spec has limits.
QP_MAX_ITER = 1000
# init's q0 check and the command check (as acroboter.sim.stateful_controller.INIT_TOLERANCE, COMMAND_TOLERANCE).
INIT_TOLERANCE = 1e-6
COMMAND_TOLERANCE = 1e-9
# After a fault the checks rejected, the commands are back within 0.1 N of an undisturbed run's within this many
# periods (tests/test_fail_safe.py: a property over generated faults; measured 3 on the default crane).
RECOVERY_PERIODS = 10
# A step more than this many periods after the last one does not integrate z over the gap.
MAX_GAP_PERIODS = 10
# The step's return codes (acroboter.sim.stateful_controller.STEP_CODES says the same in Python).
CODES = {"OK": 0, "NOT_INITIALISED": 1, "CORE_FAILED": 2, "UNTRUSTED": 3, "COASTING": 4, "LOST": 5,
         "UNSAFE_COMMAND": 6, "INVALID_Q0": 7, "NO_STATIC_COMMAND": 8}
_MATH = ("sqrt", "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "exp", "log", "pow", "fabs", "fmin", "fmax",
         "floor", "ceil", "fmod", "sinh", "cosh", "tanh", "log1p", "expm1", "copysign", "erf", "hypot")


def _comment(lines: list[str]) -> str:
    wrapped = []
    for line in lines:
        indent = " " * (len(line) - len(line.lstrip()) + 4)
        wrapped += textwrap.wrap(line, 112, subsequent_indent=indent, break_on_hyphens=False) or [""]
    return "/*\n" + "\n".join(f" * {w}".rstrip() for w in wrapped) + "\n */\n"


def macro_name(name: str) -> str:
    """A layout name as a C macro suffix: 'CC.r_x' -> 'CC_R_X', 'climbing_unit.x' -> 'CLIMBING_UNIT_X'."""
    return re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_").upper()


def _sizes(export) -> dict[str, int]:
    lay = export.step.layout
    est = export.estimator
    return {"N": lay.n, "NS": lay.n_signals, "L": lay.l, "K": lay.k, "NY": est.measured.size if est else 2 * lay.n,
            "NU": est.unmeasured.size if est else 0, "M": len(est.rows) if est else 0, "DELAY": export.delay,
            "ITERATIONS": export.iterations, "ESTIMATOR": int(est is not None),
            "PREDICT": int(bool(est and est.predict)), "MAX_COAST": est.checks.max_coast if est else 0}


def magic(export) -> int:
    """The initialised-struct marker: 64 bits of the controller's name, layout and numbers (never 0)."""
    text = f"{export.name} {sorted(_sizes(export).items())} {export.step.spec.model_hash()}"
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little") | 1


def state_bytes(export) -> int:
    """sizeof(<name>_state) on this platform (ctypes lays the struct out as the C compiler does; a test compiles
    one and compares)."""
    lay, est = export.step.layout, export.estimator
    n, d, w = lay.n, export.delay, export.work
    f64, i32, i64, ptr = ctypes.c_double, ctypes.c_int, ctypes.c_longlong, ctypes.c_void_p
    fields = [("magic", ctypes.c_ulonglong), ("k", i64), ("code", i32), ("has_t_last", i32), ("hold", i32),
              ("t_last", f64), ("saturated", f64), ("q0", f64 * n), ("sig", f64 * ((d + 1) * 3 * lay.n_signals)),
              ("q", f64 * (2 * n)), ("z", f64 * (5 * max(lay.k, 1) + 1)), ("has_t_kept", i32), ("qdd", f64 * n),
              ("u", f64 * (3 * lay.l)),
              ("phi", f64 * max(export.n_constraints, 1))]
    if est is not None:
        ew = est.work

        class Estimator(ctypes.Structure):
            _fields_ = [("d", f64 * (6 * n + (d + 1) * n + 2 * n + max(est.measured.size, 1) + n
                                     + max(est.unmeasured.size, 1) + max(len(est.rows), 1) + 2)),
                        ("k", i64), ("ints", i32 * 7), ("arg", ptr * max(ew[0], 1)), ("res", ptr * max(ew[1], 1)),
                        ("iw", i64 * max(ew[2], 1)), ("w", f64 * max(ew[3], 1))]

        fields.append(("est", Estimator))
    fields += [("arg", ptr * max(w[0], 1)), ("res", ptr * max(w[1], 1)), ("iw", i64 * max(w[2], 1)),
               ("w", f64 * max(w[3], 1))]
    return ctypes.sizeof(type("State", (ctypes.Structure,), {"_fields_": fields}))


def math_symbols(texts: list[str]) -> list[str]:
    """The libm functions the C calls (sincos where it computes a sin and a cos: gcc merges them at -O2)."""
    used = {f for f in _MATH for t in texts if re.search(rf"\b{f}\(", t)}
    if {"sin", "cos"} <= used:
        used.add("sincos")
    return sorted(used)


def _layout_lines(export) -> list[str]:
    lay, est, u = export.step.layout, export.estimator, export.name.upper()
    if est is None:
        return ["Measurement vector y (no [sensing] section, or an ideal one: the state itself, no estimator):",
                f"  y[0..{lay.n - 1}] = q, y[{lay.n}..{2 * lay.n - 1}] = qd, in the coordinate order of the layout "
                f"below (m for positions and cable lengths, unitless for the axes; per second for qd); the macros "
                f"{u}_Q_<COORDINATE> give each one's index"]
    lines = [f"Measurement vector y[{u}_NY] (the spec's [sensing] groups, in their order): y[j] is the sample of "
             f"coordinate q[{export.name}_y_coordinate[j]], taken delay_periods = {export.delay} control period(s) "
             f"before the call, as it arrives; the macro {u}_Y_<COORDINATE> is its index j:"]
    for j, i in enumerate(est.measured):
        group, unit, noise, step = export.groups[j]
        extra = f", sensor noise sd {noise:g}" if noise else ""
        extra += f", quantisation {step:g}" if step else ""
        lines.append(f"  y[{j}] = q[{i}] {export.coordinates[i]} ({group}; {unit}{extra}; gate "
                     f"{est.checks.gate[j]:.6g})")
    if est.unmeasured.size:
        lines.append("  not measured (rebuilt through phi(q) = 0): "
                     + ", ".join(f"q[{i}] {export.coordinates[i]}" for i in est.unmeasured))
    if export.delay:
        lines.append(f"  The first {export.delay} call(s) have no sample that old yet: pass the sample of the crane "
                     "at rest at q0 (the first one the sensors give; a replay passes what was recorded).")
    return lines


def _estimator_lines(export) -> list[str]:
    est, s, u = export.estimator, export.sensing, export.name.upper()
    if est is None:
        return []
    iters, c = export.iterations, est.checks
    names = [export.coordinates[est.measured[a]].rpartition("_")[0] for a, _, _ in c.axes]  # 'CC.u' of 'CC.u_x'
    axes = ", ".join(f"{n} {v:g}" for n, v in zip(names, c.axis_tolerance, strict=True)) or "(none measured whole)"
    return [
        "Estimator (acroboter.sim.sensing.Estimator, statement for statement), in each step:",
        "  1. the prediction at the sample's time: the last estimate carried over the period with the acceleration "
        "commanded then;",
        f"  2. the sample's checks (docs/sensing.md, 'Bad samples'): every y[j] finite; every fully measured unit axis "
        f"of unit length to {axes}; every y[j] within its gate of "
        f"the prediction (max_speed = {s.max_speed:g} m/s or max_axis_rate = {s.max_axis_rate:g} 1/s times T, "
        f"plus {GATE_SIGMAS:g} noise sd and one quantisation step; listed with y above), the gate widened by each "
        f"period coasted (x (1 + st->est.coasted)); the projection of the sample converged (max |phi| <= "
        f"{PROJECTION_ACCEPT:g}). A sample that fails one is rejected: the estimate is the prediction (code "
        f"{u}_COASTING); after more than {u}_MAX_COAST = {c.max_coast} rejected in a row it is lost (code {u}_LOST) "
        "until two consecutive samples pass the finite and unit-axis checks and agree within their gates: then the "
        "positions are taken from the second, the rates from the prediction. st->est.reason says why the last "
        "sample was rejected, st->est.rejected which y[j] (the struct's comments list the reasons);",
        "  3. the measured coordinates overwritten by y (unless rejected), the unmeasured ones kept from the "
        f"prediction; the projection onto phi(q, t) = 0 over the {len(est.rows)} independent constraint rows: "
        + (f"exactly {iters} Gauss-Newton least-squares steps on the unmeasured coordinates, then "
           if est.unmeasured.size else "")
        + f"at most {iters} minimal-norm steps, stopping early once max |phi| <= {PROJECTION_TOLERANCE:g};",
        f"  4. velocities: alpha-beta filter of the projected positions, both poles at exp(-T/tau), tau = "
        f"{s.velocity_filter_s!r} s: alpha = {est.alpha!r}, beta = {est.beta!r}, its prediction with the "
        "commanded acceleration; then onto phi_q qd = -phi_t (minimal-norm correction with phi_dot);",
        f"  5. delay {export.delay} period(s): the signals of the sample's time are those passed {export.delay} "
        "call(s) earlier (the first call's for the first calls); "
        + ("the estimate is carried forward to t with the accelerations commanded since the sample and projected "
           "again" if est.predict and export.delay else "the estimate is used as it is (no carrying forward)"),
        f"Recovery, without reset: after the last bad sample the step returns {u}_OK again within {u}_MAX_COAST + 2 "
        "calls (the first good sample within the widened gate while coasting, else the second of two agreeing ones "
        f"once lost; on the default crane 1 or 2 calls); after a fault the checks rejected (NaN, inf, an axis, a "
        f"jump beyond its gate, at most {u}_MAX_COAST samples long) the commands are back within 0.1 N of an "
        f"undisturbed run's within {RECOVERY_PERIODS} periods (tests/test_fail_safe.py; measured 3). A wrong sample "
        "the checks cannot tell from a motion (inside its gate, a frozen sensor while the crane moves slowly) is "
        f"used like any other. {export.name}_reinit restarts the filter from the next sample (mid-motion: positions "
        "as they come, rates from 0).",
        "",
    ]


def _stack_text(export, stack) -> str:
    if stack is None:
        return ("Stack: not measured (no C compiler with -fcallgraph-info at export): the generated functions keep "
                "their intermediate values in local variables, a few kB per step; measure with gcc -fstack-usage.")
    figures, compiler = stack
    calls = ", ".join(f"{entry.removeprefix(export.name + '_')} {size} bytes" for entry, size in figures.items())
    return (f"Stack (the deepest call chain of each call; measured at export by {compiler} -fcallgraph-info=su): "
            f"{calls}; plus libm's own frames, and the dynamic linker's lazy binding on a first call (about 3 kB "
            "where it saves the vector registers: link with -Wl,-z,now or set LD_BIND_NOW for a hard real-time "
            "loop).")


def header_text(export, symbols: list[str], stack=None) -> str:
    name, step, lay, u = export.name, export.step, export.step.layout, export.name.upper()
    est = export.estimator
    iters = export.iterations
    limits = ", ".join(f"{n} [{lo:.6g}, {hi:.6g}] {unit}" for n, lo, hi, unit in
                       zip(lay.inputs, export.command_low, export.command_high, lay.input_units, strict=True))
    lines = [
        f"{name}: the stateful ACROBOTER controller (estimator, integral action, control step, fail-safe checks).",
        "",
        f"Generated by `acroboter export-step --stateful` with CasADi {ca.__version__}. Do not edit: re-export.",
        f"  spec '{step.spec.name}', model hash {step.spec.model_hash()}, method {step.method}; the core step's gains, "
        f"formulation, solvers and limits: {name}_functions.h; ki = {step.gains.ki!r} 1/s^3",
        f"  control period T = {u}_PERIOD = {export.period!r} s (rate_hz {step.spec.controller.rate_hz:g}): call "
        f"{name}_step once per period, at t = t0 + k T",
        "",
        "Units and frames: SI throughout (m, s, N, N*m). Positions, cable lengths and the body axes u, v, w (unit "
        "vectors, unitless components) are in the world frame of the spec: its gravity "
        f"{list(step.spec.gravity)} m/s^2, each body's (u, v, w) a right-handed orthonormal triple. Every array is "
        "dense, in the layout's order (the list at the end; macros below).",
        "",
        "Calls (no heap, no globals written: everything lives in the caller's state struct; re-entrant per struct):",
        f"  int {name}_init({name}_state* st, const double* q0, const double* signals);",
        f"    q0[{u}_N]: the crane at rest at the start ({name}_q0: the spec's static equilibrium at its path's "
        "start); "
        f"signals[3 {u}_NS]: the path at t0 ({name}_path(t0, signals)). Checks q0: finite, every body's axes "
        f"right-handed orthonormal and phi(q0) = 0 to {INIT_TOLERANCE:g}, else returns {u}_INVALID_Q0 and changes "
        f"nothing; computes the static command (the core step at rest), else {u}_NO_STATIC_COMMAND; then reset. "
        f"step, reset and reinit refuse a struct init never accepted ({u}_NOT_INITIALISED: st->magic is "
        f"{u}_MAGIC only after a successful init, so zeroed or uninitialised memory is refused)",
        f"  int {name}_reset({name}_state* st);  a new run from rest at init's q0: z = 0, the filter and the delay "
        "line emptied, the safe command the static one",
        f"  int {name}_reinit({name}_state* st);  restart the estimator from the next sample, mid-motion (z, the delay "
        "line and the safe command kept)",
        f"  int {name}_step({name}_state* st, const double* y, double t, const double* signals, double* u);",
        f"    y[{u}_NY]: the measurements (below); t: the time (s; a t before the last one starts a new integral); "
        f"signals[3 {u}_NS] = [s; sd; sdd]: the desired path at t ({name}_path(t, signals)); u[{u}_L]: the command "
        "(always written)",
        f"  void {name}_path(double t, double* signals);  the spec's path at t (s): [s; sd; sdd] in the signal "
        "layout below (m, m/s, m/s^2; the yaw in rad, rad/s, rad/s^2): rest-to-rest quintic edges through the "
        "waypoints, the yaw one quintic over the whole path, moving anchors following x and y; the same bits as "
        f"acroboter's DesiredPath.flat. It lasts {export.path_numbers[4]:.6g} s; before t = 0 it holds its start, "
        "after its end its last waypoint, at rest",
        f"  A step whose t or signals are not finite returns {u}_UNTRUSTED and changes nothing; a step more than "
        f"{MAX_GAP_PERIODS} periods after the last one does not integrate z over the gap; a step that returns "
        f"anything but {u}_OK or {u}_COASTING leaves z as it was.",
        "",
        "Return codes of step (and init); after every code but 1, u holds a command within the bounds below "
        f"({name}_u_low, {name}_u_high):",
        f"  {u}_OK 0: the sample was accepted, u computed from it",
        f"  {u}_NOT_INITIALISED 1: init never succeeded on this struct: u is NOT written, nothing changed",
        f"  {u}_CORE_FAILED 2: the core step failed (its bounded QP did not converge): u = the safe command",
        f"  {u}_UNTRUSTED 3: the estimate or the core's command is not finite, or the estimate is off the constraints "
        f"(max |phi| > {PROJECTION_ACCEPT:g}): u = the safe command",
        f"  {u}_COASTING 4: the sample was rejected (st->est.reason): the estimate is the prediction, u computed "
        "from it and checked; z is not advanced over the period",
        f"  {u}_LOST 5: more than {u}_MAX_COAST samples rejected in a row: u = the safe command until two "
        "consecutive samples agree again",
        f"  {u}_UNSAFE_COMMAND 6: the command is outside the limits or the sanity bound: u = the safe command",
        f"  (init) {u}_INVALID_Q0 7, {u}_NO_STATIC_COMMAND 8: see init",
        "  The safe command (st->u_safe) is the last command returned with code 0 or 4; after init and reset the "
        "static command that holds the crane at rest at q0 (st->u_static). The caller decides what a run of "
        "non-zero codes means for the crane (a supervisor's stop): the controller never commands beyond the bounds.",
        f"  Bounds of u (the spec's limits within the sanity bound: forces at most 5 x the crane's weight, torques "
        f"that times the largest body lever; each to {COMMAND_TOLERANCE:g} relative): {limits}",
        "  After a step: st->q, st->qd hold the estimate it used, st->z the integral, st->qdd the commanded "
        "acceleration, st->code the code" + (", st->est the estimator (its status, reason, jump, coasted)"
                                             if est else ""),
        "",
        *_layout_lines(export),
        "",
        *_estimator_lines(export),
        "Integral action (acroboter.control.controllers.Controller._integrate): z += 0.5 (t - t_prev) "
        "(sigma_prev + sigma) with sigma at the estimate and the signals at t; held over the period after a "
        "saturated step (conditional integration, the anti-windup; the core step's judgement) and over a period "
        "whose sample was rejected; ki = 0: z stays 0 and nothing of it runs.",
        "",
        "Fixed iteration counts per step: "
        + (f"{iters} unmeasured least-squares steps and " if export.unmeasured.size else "")
        + (f"<= {iters} projection steps per projection, at most 2 projections of the sample (its own, and the "
           "prediction's where the sample's did not converge) plus one at t with a delay, 1 or 2 rate corrections; "
           if est else "no estimator; ")
        + f"every linear solve a fixed SX Cholesky or CasADi's ldl/qr; the bounded QP ({QP_PLUGIN}), where a spec "
        f"has limits, at most {QP_MAX_ITER} iterations.",
        f"Memory: sizeof({name}_state) = {state_bytes(export)} bytes (x86-64, LP64), the caller's; no heap.",
        _stack_text(export, stack),
        f"Link with -lm: the code calls {', '.join(symbols)} from libm (and the compiler may emit memset, memcpy "
        "or memmove). Compile with -O2, never -ffast-math (the checks need NaN and inf).",
        "",
        "Layout (the macros below give each index):",
    ]
    lines += [f"  q[{i}]  {c}" for i, c in enumerate(lay.coordinates)]
    lines += [f"  s[{i}]  {c}" for i, c in enumerate(lay.signals)]
    lines += [f"  u[{i}]  {c} ({unit})" for i, (c, unit) in enumerate(zip(lay.inputs, lay.input_units, strict=True))]
    lines += [f"  z[{i}]  {c}" for i, c in enumerate(lay.servo_constraints)]
    return _comment(lines)


def _macros(export) -> str:
    lay, est, u = export.step.layout, export.estimator, export.name.upper()
    notes = {"N": "natural coordinates q", "NS": "path signals (s, sd and sdd have NS each)", "L": "inputs u",
             "K": "servo-constraints (z)", "NY": "measurements y", "NU": "coordinates not measured",
             "M": "independent constraint rows of the projection", "DELAY": "measurement delay, control periods",
             "ITERATIONS": "Gauss-Newton steps of a projection", "ESTIMATOR": "1: y is measurements, 0: y = [q; qd]",
             "PREDICT": "1: the delayed estimate is carried forward to t",
             "MAX_COAST": "rejected samples in a row before the estimate is lost"}
    lines = [f"#define {u}_{key} {value} /* {notes[key]} */" for key, value in _sizes(export).items()]
    lines += [f"#define {u}_PERIOD {export.period!r} /* control period T, s */",
              f"#define {u}_MAGIC 0x{magic(export):016x}ULL /* st->magic after a successful init */"]
    lines += [f"#define {u}_{code} {value}" for code, value in CODES.items()]
    lines += [f"#define {u}_Q_{macro_name(c)} {i}" for i, c in enumerate(lay.coordinates)]
    lines += [f"#define {u}_S_{macro_name(c)} {i}" for i, c in enumerate(lay.signals)]
    lines += [f"#define {u}_U_{macro_name(c)} {i}" for i, c in enumerate(lay.inputs)]
    if est is not None:
        lines += [f"#define {u}_Y_{macro_name(export.coordinates[i])} {j}" for j, i in enumerate(est.measured)]
    return "\n".join(lines)


def _numbers(values) -> str:
    return ", ".join(repr(float(v)) for v in values)


def render_controller(export, function_text: str, stack=None) -> tuple[str, str]:
    """(<name>.h, <name>.c); `function_text`: the generated functions' C (for the libm symbols it calls); `stack`:
    acroboter.codegen.stack_usage.measure_stack's figures, or None (not measured)."""
    name, lay, est = export.name, export.step.layout, export.estimator
    u, n = name.upper(), lay.n
    sizes = _sizes(export)
    est_struct = est_code = ""
    if est is not None:
        est_struct, est_code = estimator_text(est, api="static")
    path_code = render("path.c", NAME=f"{name}_path", API="static ")
    source_defines = [f"#define {key} {u}_{key}" for key in sizes]
    source_defines += [f"#define {code} {u}_{code}" for code in CODES]
    bodies = list(lay.body_offset.values())
    source_defines += [
        f"#define K1 {max(lay.k, 1)}", f"#define M_ALL {max(export.n_constraints, 1)}", f"#define NB {len(bodies)}",
        f"#define KI {export.step.gains.ki!r}", f"#define MAGIC {u}_MAGIC",
        f"#define INIT_TOLERANCE {INIT_TOLERANCE!r}", f"#define COMMAND_TOLERANCE {COMMAND_TOLERANCE!r}",
        f"#define PROJECTION_ACCEPT {PROJECTION_ACCEPT!r}", f"#define MAX_GAP {MAX_GAP_PERIODS * export.period!r}",
        f"const double {name}_u_low[{lay.l}] = {{{_numbers(export.command_low)}}};",
        f"const double {name}_u_high[{lay.l}] = {{{_numbers(export.command_high)}}};",
        f"static const casadi_int bodies[{len(bodies)}] = {{{', '.join(map(str, bodies))}}};",
        f"static const double path_table[{export.path_numbers.size}] = {{{_numbers(export.path_numbers)}}};",
        f"const double {name}_q0[{n}] = {{{_numbers(export.start_q)}}};",
        f"const int {name}_y_coordinate[{sizes['NY']}] = "
        f"{{{', '.join(map(str, est.measured if est is not None else range(sizes['NY'])))}}};",
        "",
        f"void {name}_path(double t, double* signals) {{ {name}_path_flat(path_table, t, signals); }}",
    ]
    source = render("controller.c", NAME=name, DEFINES="\n".join(source_defines[:-2]), ESTIMATOR_CODE=est_code,
                    PATH_CODE=path_code + "\n" + "\n".join(source_defines[-2:]) + "\n")
    symbols = math_symbols([function_text, source])
    w = export.work
    header_body = render(
        "controller.h", GUARD=f"{u}_H", NAME=name, UNAME=u, MACROS=_macros(export), ESTIMATOR_STRUCT=est_struct,
        ESTIMATOR_MEMBER=(f"  {name}_estimator est;               /* the estimator (acroboter.sim.sensing) */\n"
                          if est is not None else ""),
        STATE_BYTES=state_bytes(export), N=n, DELAY1=export.delay + 1, NS3=3 * lay.n_signals, K1=max(lay.k, 1),
        L=lay.l, M_ALL=max(export.n_constraints, 1), NY=sizes["NY"], SZ_ARG=max(w[0], 1), SZ_RES=max(w[1], 1),
        SZ_IW=max(w[2], 1), SZ_W=max(w[3], 1))
    return header_text(export, symbols, stack) + header_body, source
