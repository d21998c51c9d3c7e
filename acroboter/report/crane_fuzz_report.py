"""The report of the fuzz over generated cranes (docs/plant-fuzz-cranes.md): the cranes' ranges, the verdict of each
check, the worst case of each measure with the command that replays it (rows of acroboter.studies.generated_cranes)."""

from __future__ import annotations

from ..studies.generated_cranes import (
    CLOSED_LOOP_BOUND_M,
    CLOSED_LOOP_MUJOCO_S,
    REJECT_SHARE,
    TRACKING_BOUND_M,
)
from .plant_fuzz_report import report as open_loop_report

RANGES = [("winches", "winches", "{:.0f}"), ("cc_mass_kg", "connector mass (kg)", "{:.3g}"),
          ("su_mass_kg", "unit mass (kg)", "{:.3g}"), ("min_drum_kg", "lightest drum (kg)", "{:.3g}"),
          ("max_drum_kg", "heaviest drum (kg)", "{:.3g}"), ("main_cable_m", "main cable (m)", "{:.3g}"),
          ("cc_radius_m", "connector anchor radius (m)", "{:.3g}"), ("su_radius_m", "unit anchor radius (m)", "{:.3g}"),
          ("drop_m", "drop between the anchor planes (m)", "{:.3g}"),
          ("min_start_share", "least winch tension at rest (static shares)", "{:.3g}")]
CLOSED_MEASURES = [("max_error_mm", "tracking error, whole path, own plant (mm)"),
                   ("mujoco_max_error_mm", "tracking error on MuJoCo (mm)"),
                   ("plants_max_diff_m", "bodies' centres, own plant against MuJoCo, closed loop (m)")]


def crane_report(cranes: list[dict], open_rows: list[dict], closed_rows: list[dict], wall_s: float, workers: int,
                 mujoco_timestep: float) -> str:
    """Markdown: the cranes drawn and their ranges, each check's verdict, the worst cases, the open-loop report."""
    accepted = [c for c in cranes if not c["status"].startswith("rejected")]
    failed = [c for c in accepted if not c["status"] == "agrees"]
    lines = [f"# Generated cranes: {len(accepted)} cranes, {len(open_rows)} open-loop experiments, "
             f"{len(closed_rows)} closed-loop runs", "",
             f"**{len(accepted) - len(failed)} of {len(accepted)} cranes pass every check**; {len(failed)} fail; "
             f"{len(cranes) - len(accepted)} drawn cranes were rejected (no static equilibrium with every winch "
             f"pulling at least {REJECT_SHARE:g} of its static share, or within its limits).", "",
             "Each accepted crane: its code generated twice is the same bytes; open-loop experiments on the own plant "
             "and MuJoCo (the rules below); every method over the whole path, the paper's scaled to the crane's "
             f"connector, on the own plant within {TRACKING_BOUND_M * 1e3:g} mm and no input on a limit; the first "
             f"{CLOSED_LOOP_MUJOCO_S:g} s of it on both plants, each in its own closed loop, the bodies' centres "
             f"within {CLOSED_LOOP_BOUND_M * 1e6:g} µm.", "",
             "## The cranes drawn (accepted)", "", "| quantity | least | most |", "|---|---|---|"]
    for key, label, fmt in RANGES:
        values = [c[key] for c in accepted if c.get(key) is not None]
        if values:
            lines.append(f"| {label} | {fmt.format(min(values))} | {fmt.format(max(values))} |")
    deterministic = sum(bool(c.get("deterministic_code")) for c in accepted)
    lines += ["", f"Code generated twice, the same bytes: {deterministic} of {len(accepted)}.", ""]
    if closed_rows:
        lines += ["## Closed loop: the worst case of each measure", ""]
        for key, label in CLOSED_MEASURES:
            worst = max(closed_rows, key=lambda r: r[key])
            lines.append(f"- {label}: {worst[key]:.3g} ({worst['crane']}, {worst['method']}, {worst['status']}): "
                         f"`{worst['replay']}`")
        per_method = sorted({r["method"] for r in closed_rows})
        lines += ["", "| method | runs | failed | worst tracking (mm) | worst plants' difference (µm) |",
                  "|---|---|---|---|---|"]
        for method in per_method:
            mine = [r for r in closed_rows if r["method"] == method]
            lines.append(f"| {method} | {len(mine)} | {sum(not r['passed'] for r in mine)} | "
                         f"{max(r['max_error_mm'] for r in mine):.3g} | "
                         f"{max(r['plants_max_diff_m'] for r in mine) * 1e6:.3g} |")
        lines.append("")
        lines += _unstable_loops(closed_rows)
    if failed:
        lines += ["## Cranes that fail a check", ""]
        lines += [f"- {c['crane']}: {c['status']}" for c in failed[:80]]
        lines.append("")
    rejected = [c for c in cranes if c["status"].startswith("rejected")]
    if rejected:
        lines += ["## Rejected cranes", ""]
        lines += [f"- {c['crane']}: {c['status'].removeprefix('rejected: ')}" for c in rejected[:40]]
        lines.append("")
    if open_rows:
        text = open_loop_report(open_rows, wall_s, workers, mujoco_timestep)
        lines += ["## Open loop", ""] + ["#" + line if line.startswith("#") else line for line in text.splitlines()[1:]]
    return "\n".join(lines) + "\n"


def _unstable_loops(closed_rows: list[dict]) -> list[str]:
    """The cranes whose loop is unstable at the start (acroboter.sim.loop_stability), by cause, with the methods."""
    causes: dict[tuple[str, str], list[str]] = {}
    for r in closed_rows:
        if r.get("loop_cause"):
            causes.setdefault((r["crane"], r["loop_cause"]), []).append(r["method"])
    if not causes:
        return ["Every loop is stable at the start (acroboter.sim.loop_stability).", ""]
    lines = [f"Loops unstable at the start (acroboter.sim.loop_stability), {len({c for c, _ in causes})} cranes:"]
    for (crane, cause), methods in sorted(causes.items()):
        growth = max((r["zero_dynamics_growth_per_s"] if cause == "zero dynamics" else r["sampled_growth_per_s"])
                     for r in closed_rows if r["crane"] == crane and r["method"] in methods)
        lines.append(f"- {crane}: {cause}, growing at up to {growth:.3g} 1/s ({', '.join(methods)})")
    return lines + [""]
