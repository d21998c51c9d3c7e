"""Judging a grid's rows: which runs are good, how the others fail, and the text that says so.

A row (acroboter.studies.penalty_grid.COLUMNS) is *good* when its run finished (status 'ok') and its max
position error is within `tolerance` times the reference's (MLM: no penalty numbers, so the best the
crane's model allows at these gains). A run that is not good falls in one category (`category`):

    diverged   the closed loop blew up (the plant stopped the run)
    not-pd     A was not positive definite in floating point (the Cholesky factorization failed)
    error      any other failure
    ill        finished, but cond(A) > ILL_CONDITIONED: round-off decides the commanded q̈
    soft       finished, but q̈ misses the (servo-)constraints by > SOFT_RESIDUAL: α is too small
    large      finished, neither of the above, and still outside the tolerance

`format_table` is the error table the sweep prints; `findings` the lines below it (and in the
docs/studies.md): per method the contiguous α range that is good, and how the runs below and above it break
down, then how much Ω matters and how many runs did not finish.
"""

from __future__ import annotations

import math
import re

from .penalty_grid import method_name, x_key, x_label, x_symbol

# Condition number of A above which a run outside the good range is called ill-conditioned (eps · cond > 0.2).
ILL_CONDITIONED = 1e15
# Above this |φ_q q̈ + ρ| or |σ_q q̈ + ρ_s| a run outside the good range is called soft (penalty too small).
SOFT_RESIDUAL = 1e-8
FAILURE_NAMES = {"diverged": "diverged", "not-pd": "A not positive definite", "error": "other errors"}


# ---------------------------------------------------------------------------------------------------
# Rows


def ok(row: dict) -> bool:
    return row.get("status") == "ok"


def max_error(row: dict) -> float:
    """The run's max position error (mm); NaN for a run that did not finish (never 'good')."""
    return row["max_position_error_mm"] if ok(row) and row["max_position_error_mm"] is not None else math.nan


def mlm_row(rows: list[dict]) -> dict | None:
    return next((r for r in rows if r["method"] == "mlm"), None)


def penalty_methods(rows: list[dict]) -> list[str]:
    """The penalty methods in the rows, by iteration count (penalty, iterative-3, ...)."""
    penalty = sorted({r["iterations"] for r in rows if r["method"] != "mlm" and r["iterations"] is not None})
    return [method_name(n) for n in penalty]


def category(row: dict) -> str:
    """How a run outside the good range fails: diverged, not-pd, error, ill, soft or large."""
    status = row.get("status") or ""
    if status.startswith("diverged"):
        return "diverged"
    if "not positive definite" in status:
        return "not-pd"
    if not ok(row):
        return "error"
    cond = row.get("cond_penalty_matrix")
    if cond is not None and cond > ILL_CONDITIONED:
        return "ill"
    soft = max(row.get("max_servo_accel_residual") or 0.0, row.get("max_constraint_accel_residual") or 0.0)
    return "soft" if soft > SOFT_RESIDUAL else "large"


def fmt_range(values: list[float], fmt: str, unit: str = "") -> str:
    """'lo..hi' in `fmt`, or one value when they print alike."""
    lo, hi = min(values), max(values)
    text = format(lo, fmt) if lo == hi or format(lo, fmt) == format(hi, fmt) else f"{lo:{fmt}}..{hi:{fmt}}"
    return text + unit


# ---------------------------------------------------------------------------------------------------
# Along one axis (rows sorted by the swept value)


def good_band(group: list[dict], limit: float) -> tuple[int, int] | None:
    """Indices (lo, hi) of the widest contiguous run of good rows (finished, error <= limit)."""
    good = [ok(r) and max_error(r) <= limit for r in group]
    best = None
    i = 0
    while i < len(group):
        j = i
        while j < len(group) and good[j]:
            j += 1
        if j > i and (best is None or j - i > best[1] - best[0] + 1):
            best = (i, j - 1)
        i = max(j, i + 1)
    return best


def segments(group: list[dict], indices) -> list[list[dict]]:
    """Runs in the order of `indices`, split where the failure category changes."""
    out: list[list[dict]] = []
    for i in indices:
        r = group[i]
        if out and category(out[-1][0]) == category(r):
            out[-1].append(r)
        else:
            out.append([r])
    return out


def describe(segment: list[dict], ref_err: float, xk: str, symbol: str = "α") -> str:
    """One clause on a segment of one category: how it fails, and where on the axis."""
    kind = category(segment[0])
    where = f"{symbol} = " + fmt_range([r[xk] for r in segment], ".0e")
    errs = [r["max_position_error_mm"] for r in segment if ok(r)]
    err = (f"error {fmt_range(errs, '.3g', ' mm')} = {fmt_range([e / ref_err for e in errs], '.3g')}x MLM"
           if errs else "")
    conds = [r["cond_penalty_matrix"] for r in segment if r.get("cond_penalty_matrix") is not None
             and math.isfinite(r["cond_penalty_matrix"])]
    if kind == "diverged":
        times = [float(re.search(r"t = ([-+0-9.eE]+)", r["status"]).group(1)) for r in segment]
        whys = sorted({m.group(1) for r in segment if (m := re.search(r"\((.*)\)$", r["status"]))})
        why = f": {'; '.join(whys)}" if whys else ""
        return f"the loop diverges (at t = {fmt_range(times, 'g', ' s')}{why}) at {where}"
    if kind == "not-pd":
        cond = f"; cond(A) {fmt_range(conds, '.1e')} at the start, beyond 1/eps" if conds else ""
        return f"A is not positive definite in floating point (Cholesky fails{cond}) at {where}"
    if kind == "error":
        return f"{segment[0]['status'][:100]} at {where}"
    if kind == "ill":
        return f"ill-conditioned A (cond {fmt_range(conds, '.1e')}): {err} at {where}"
    if kind == "soft":
        servo = max(r.get("max_servo_accel_residual") or 0.0 for r in segment)
        geo = max(r.get("max_constraint_accel_residual") or 0.0 for r in segment)
        return (f"soft penalty (commanded q̈ misses the servo-constraints by |σ_q q̈ + ρ_s| <= {servo:.2g}, the "
                f"geometric ones by |φ_q q̈ + ρ| <= {geo:.2g}): {err} at {where}")
    return f"{err} at {where}"


# ---------------------------------------------------------------------------------------------------
# The text


def format_table(rows: list[dict], alpha_mode: str = "tied") -> str:
    """Max position error (mm) per method and Ω (and α̂ in grid mode) against the swept α."""
    xk = x_key(alpha_mode)
    xs = sorted({r[xk] for r in rows if r["method"] != "mlm"})
    label = "method         Ω" + ("      α̂" if alpha_mode == "grid" else "")
    width = 16 + (8 if alpha_mode == "grid" else 0)
    head = f"{label:<{width}}" + "".join(f"{x:>9.0e}" for x in xs)
    lines = [f"max position error (mm) vs {x_label(alpha_mode)}; div = diverged, err = error", head,
             "-" * len(head)]
    groups: dict[tuple, dict] = {}
    for r in rows:
        if r["method"] == "mlm":
            continue
        g = (r["iterations"], r["omega"], r["alpha_servo"] if alpha_mode == "grid" else None)
        groups.setdefault(g, {})[r[xk]] = r
    for (n, omega, aserv), by_x in sorted(groups.items()):
        name = f"{method_name(n):<12} {omega:>3g}" + (f" {aserv:7.0e}" if alpha_mode == "grid" else "")
        cells = []
        for x in xs:
            r = by_x.get(x)
            if r is None:
                cells.append(f"{'':>9}")
            elif ok(r):
                cells.append(f"{r['max_position_error_mm']:9.3g}")
            else:
                cells.append(f"{'div' if r['status'].startswith('diverged') else 'err':>9}")
        lines.append(f"{name:<{width}}" + "".join(cells))
    ref = mlm_row(rows)
    if ref is not None:
        value = f"{ref['max_position_error_mm']:.3g} mm" if ok(ref) else ref["status"]
        lines.append(f"mlm (no penalty numbers): {value}")
    return "\n".join(lines)


def findings(rows: list[dict], alpha_mode: str = "tied", tolerance: float = 2.0) -> list[str]:
    """Per method (Ω values with the same outcome merged): the contiguous α range within `tolerance` x
    MLM's max position error, and how the runs below and above it break down."""
    ref = mlm_row(rows)
    if ref is None or not ok(ref):
        return ["no MLM reference: " + (ref["status"] if ref else "not in the grid")]
    ref_err = ref["max_position_error_mm"]
    limit = tolerance * ref_err
    lines = [f"reference: MLM max position error {ref_err:.3g} mm; 'good' = finished and max error <= "
             f"{tolerance:g}x MLM = {limit:.3g} mm"]
    groups: dict[tuple, dict[float, list[dict]]] = {}
    for r in rows:
        if r["method"] != "mlm":
            g = (r["iterations"], r["alpha_servo"] if alpha_mode == "grid" else None)
            groups.setdefault(g, {}).setdefault(r["omega"], []).append(r)
    for (n, aserv), by_omega in sorted(groups.items()):
        label = method_name(n) + (f", α̂ = {aserv:.0e}" if alpha_mode == "grid" else "")
        lines += _method_findings(label, by_omega, alpha_mode, tolerance, ref_err)
    lines += _omega_spread(rows, limit)
    lines += _failures(rows)
    return lines


def _method_findings(label: str, by_omega: dict[float, list[dict]], alpha_mode: str, tolerance: float,
                     ref_err: float) -> list[str]:
    """The lines of one method: one per set of Ω values whose runs have the same outcome along α."""
    xk, symbol, limit = x_key(alpha_mode), x_symbol(alpha_mode), tolerance * ref_err
    # Outcome of each Ω: the band and the (kind, α values) of the segments below and above it; Ω values
    # with the same outcome share one line (they usually do: Ω matters little, see _omega_spread).
    outcomes: dict[tuple, list[tuple[list[dict], tuple | None]]] = {}
    for omega in sorted(by_omega):
        group = sorted(by_omega[omega], key=lambda r: r[xk])
        band = good_band(group, limit)
        if band is None:
            shape: tuple = ("none",)
        else:
            lo, hi = band
            below = segments(group, range(lo - 1, -1, -1))
            above = segments(group, range(hi + 1, len(group)))
            shape = (group[lo][xk], group[hi][xk],
                     tuple((category(s[0]), tuple(r[xk] for r in s)) for s in below),
                     tuple((category(s[0]), tuple(r[xk] for r in s)) for s in above))
        outcomes.setdefault(shape, []).append((group, band))
    lines = []
    for shape, members in outcomes.items():
        omegas = ", ".join(f"{g[0]['omega']:g}" for g, _ in members)
        head = f"{label} (Ω = {omegas}): "
        if shape == ("none",):
            finished = [r for g, _ in members for r in g if ok(r)]
            if finished:
                best = min(finished, key=max_error)
                lines.append(head + f"never within {tolerance:g}x MLM; best {best['max_position_error_mm']:.3g} "
                                    f"mm at {symbol} = {best[xk]:.0e}")
            else:
                lines.append(head + "no run finished: " + "; then ".join(
                    describe([r for g, _ in members for r in seg], ref_err, xk, symbol)
                    for seg in segments(members[0][0], range(len(members[0][0])))))
            continue
        group0, (lo0, hi0) = members[0]
        errs = [max_error(r) for g, (lo, hi) in members for r in g[lo : hi + 1]]
        decades = math.log10(group0[hi0][xk] / group0[lo0][xk])
        text = (f"good for {group0[lo0][xk]:.0e} <= {symbol} <= {group0[hi0][xk]:.0e} ({decades:g} decades, "
                f"error {fmt_range(errs, '.3g', ' mm')})")
        if lo0 == 0 and hi0 == len(group0) - 1:
            text += ", i.e. the whole grid"
        for side, indices in (("below", lambda g, lo, hi: range(lo - 1, -1, -1)),
                              ("above", lambda g, lo, hi: range(hi + 1, len(g)))):
            per_member = [segments(g, indices(g, lo, hi)) for g, (lo, hi) in members]
            if not per_member[0]:
                continue
            # Same shape: the k-th segment of every member has the same kind and α values; merged, the
            # clause's error and cond ranges cover all of the line's Ω values.
            merged = [[r for segs in per_member for r in segs[k]] for k in range(len(per_member[0]))]
            text += f"\n    {side}: " + "; then ".join(describe(seg, ref_err, xk, symbol) for seg in merged)
        lines.append(head + text)
    return lines


def _omega_spread(rows: list[dict], limit: float) -> list[str]:
    """How much Ω matters: spread of the max error over Ω at the same method and penalty numbers."""
    spread: dict[tuple, list[float]] = {}
    conds: dict[tuple, float] = {}
    for r in rows:
        if r["method"] == "mlm":
            continue
        key = (r["iterations"], r["alpha_geometric"], r["alpha_servo"])
        if ok(r):
            spread.setdefault(key, []).append(max_error(r))
        if r.get("cond_penalty_matrix") is not None:
            conds[key] = max(conds.get(key, 0.0), r["cond_penalty_matrix"])
    spreads = [(max(v) / min(v) - 1, max(v) <= limit and conds.get(k, 0.0) <= ILL_CONDITIONED)
               for k, v in spread.items() if len(v) > 1 and min(v) > 0]
    if not spreads:
        return []
    in_band = [s for s, good in spreads if good]
    text = (f"at most {100 * max(in_band):.2g} % where good and cond(A) <= {ILL_CONDITIONED:.0e}, "
            if in_band else "")
    return [f"Ω: at equal method and penalty numbers the max error differs between the Ω values by "
            f"{text}at most {100 * max(s for s, _ in spreads):.2g} % over all finished runs"]


def _failures(rows: list[dict]) -> list[str]:
    failed = [r for r in rows if not ok(r)]
    if not failed:
        return []
    kinds: dict[str, int] = {}
    for r in failed:
        kinds[category(r)] = kinds.get(category(r), 0) + 1
    return [f"{len(failed)} of {len(rows)} runs did not finish: "
            + ", ".join(f"{count} {FAILURE_NAMES[k]}" for k, count in kinds.items())]
