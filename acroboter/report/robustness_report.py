"""Judging a robustness study's rows (acroboter.studies.robustness_grid): the tables and the findings.

`summarize` turns the rows into the numbers summary.json keeps: per (method, ki) the success rate
at the paper's bounds, divergences and the distribution of the max error; per bin of the SU + CC
mass error the success rate of each (method, ki). `format_table` and `findings` are what the CLI prints.
"""

from __future__ import annotations

import math

from ..studies.robustness_grid import POSITION_BOUND_MM, SETTLE_S, YAW_BOUND_DEG

MASS_BINS = 10  # the same bins as the success figure (acroboter.report.study_figures.robustness_figures)


def _quantile(values: list[float], q: float) -> float | None:
    import numpy as np

    return float(np.quantile(values, q)) if values else None


def summarize(rows: list[dict], methods, kis, bins: int = MASS_BINS, key: str = "tracked_mass_error") -> dict:
    """The per-(method, ki) statistics and the success rates per bin of `key` (default the tracked body's
    relative mass error: on the default crane the CC hangs on the fixed main cable and only the SU's
    mass moves the PD law's steady error; `mass_error` is SU + CC)."""
    import numpy as np

    stats = []
    for m in methods:
        for ki in kis:
            sel = [r for r in rows if r.get("method") == m and r.get("ki") == ki]
            done = [r for r in sel if r.get("status") == "ok"]
            errs = [r["max_position_error_mm"] for r in done]
            settled = [r["max_position_error_settled_mm"] for r in done
                       if r.get("max_position_error_settled_mm") is not None]
            stats.append({
                "method": m, "ki": ki, "runs": len(sel), "ok": len(done),
                "diverged": sum(bool(r.get("diverged")) for r in sel),
                "success": sum(bool(r.get("success")) for r in sel),
                "success_rate": sum(bool(r.get("success")) for r in sel) / len(sel) if sel else math.nan,
                "success_settled_rate": (sum(bool(r.get("success_settled")) for r in sel) / len(sel)
                                         if sel and all(r.get("success_settled") is not None for r in sel)
                                         else None),
                "max_error_mm": {"median": _quantile(errs, 0.5), "p95": _quantile(errs, 0.95),
                                 "max": max(errs) if errs else None},
                "rms_error_mm_median": _quantile([r["rms_position_error_mm"] for r in done], 0.5),
                "settled_max_error_mm": {"median": _quantile(settled, 0.5), "p95": _quantile(settled, 0.95),
                                         "max": max(settled) if settled else None},
                "max_yaw_error_deg": max((r["max_yaw_error_deg"] or 0.0 for r in done), default=None),
                "time_saturated_s_max": max((r["time_saturated_s"] for r in done), default=None),
            })
    mass = [r[key] for r in rows if r.get(key) is not None]
    by_bin = []
    if mass:
        edges = np.linspace(min(mass), max(mass), bins + 1)
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            entry = {"key": key, "low": float(lo), "high": float(hi), "rates": {}}
            for m in methods:
                for ki in kis:
                    sel = [r for r in rows if r.get("method") == m and r.get("ki") == ki
                           and lo <= r[key] <= hi]
                    entry["samples"] = len(sel)
                    entry["rates"][f"{m} ki={ki:g}"] = (sum(bool(r["success"]) for r in sel) / len(sel)
                                                        if sel else None)
                    entry.setdefault("settled_rates", {})[f"{m} ki={ki:g}"] = (
                        sum(bool(r["success_settled"]) for r in sel) / len(sel) if sel else None)
            by_bin.append(entry)
    return {"per_method": stats, "by_mass_error": by_bin}


def _f(v, fmt="8.2f") -> str:
    return f"{v:{fmt}}" if v is not None else " " * (int(fmt.split(".")[0]) - 1) + "-"


def format_table(summary: dict) -> str:
    head = (f"{'method':<13}{'ki':>8}{'success':>9}{'settled':>9}{'diverged':>9}{'max err':>9}{'p95':>9}{'worst':>9}"
            f"{'settled':>9}{'p95':>9}{'max yaw':>9}")
    units = f"{'':<13}{'1/s³':>8}{'%':>9}{'%':>9}{'':>9}{'mm':>9}{'mm':>9}{'mm':>9}{'mm':>9}{'mm':>9}{'deg':>9}"
    lines = [head, units, "-" * len(head)]
    for s in summary["per_method"]:
        e, st = s["max_error_mm"], s["settled_max_error_mm"]
        settled = s["success_settled_rate"]
        lines.append(f"{s['method']:<13}{s['ki']:>8.3f}{100 * s['success_rate']:>9.1f}"
                     f"{'-' if settled is None else format(100 * settled, '.1f'):>9}{s['diverged']:>9d}"
                     f" {_f(e['median'])} {_f(e['p95'])} {_f(e['max'])} {_f(st['median'])} {_f(st['p95'])}"
                     f" {_f(s['max_yaw_error_deg'], '8.3f')}")
    lines.append(f"success: max position error ≤ {POSITION_BOUND_MM} mm and max yaw error ≤ {YAW_BOUND_DEG}° over "
                 f"the run (settled: from t = {SETTLE_S:g} s on); max err: median over samples, p95, worst; "
                 f"settled: the max error from t = {SETTLE_S:g} s on")
    return "\n".join(lines)


def findings(summary: dict) -> list[str]:
    """Which method wins (success rate; ties within one sample are no win), what ki buys, where none succeeds."""
    out = []
    stats = summary["per_method"]
    kis = sorted({s["ki"] for s in stats})
    for ki in kis:
        sel = sorted((s for s in stats if s["ki"] == ki), key=lambda s: -s["success_rate"])
        best, rest = sel[0], sel[1:]
        runs = max(best["runs"], 1)
        tied = [s["method"] for s in rest if (best["success"] - s["success"]) <= max(1, 0.01 * runs)]
        label = "PD law (ki = 0)" if ki == 0 else f"integral action (ki = {ki:g})"
        rates = ", ".join(f"{s['method']} {100 * s['success_rate']:.1f} %" for s in sel)
        if tied:
            out.append(f"{label}: no clear winner, {best['method']} and {', '.join(tied)} within one sample / 1 % "
                       f"({rates})")
        else:
            out.append(f"{label}: {best['method']} wins ({rates})")
    if len(kis) == 2:
        for m in dict.fromkeys(s["method"] for s in stats):
            a, b = (next(s for s in stats if s["method"] == m and s["ki"] == k) for k in kis)
            ea, eb = a["settled_max_error_mm"]["median"], b["settled_max_error_mm"]["median"]
            settled = (f"; median settled error {ea:.2f} → {eb:.2f} mm" if ea is not None and eb is not None else "")
            if a["success_settled_rate"] is not None and b["success_settled_rate"] is not None:
                settled += (f"; success from t = {SETTLE_S:g} s on {100 * a['success_settled_rate']:.1f} → "
                            f"{100 * b['success_settled_rate']:.1f} %")
            out.append(f"{m}: integral action moves success {100 * a['success_rate']:.1f} → "
                       f"{100 * b['success_rate']:.1f} %{settled}")
    none = [b for b in summary["by_mass_error"] if b["rates"] and all(not v for v in b["rates"].values())]
    if none:
        spans = ", ".join(f"{100 * b['low']:+.1f}..{100 * b['high']:+.1f} %" for b in none)
        out.append(f"no method succeeds in any sample with a tracked-body mass error of {spans}")
    return out
