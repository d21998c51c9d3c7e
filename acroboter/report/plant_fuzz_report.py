"""The plant fuzz's report (docs/plant-fuzz.md): the verdict, the figures per spec, the worst case of each measure
with its replay line, from the rows of acroboter.studies.plant_differential."""

from __future__ import annotations

from ..studies.plant_differential import (
    CONFIRM_TIMESTEPS,
    IMPACT_BEFORE_S,
    IMPACT_ENERGY_J,
    IMPACT_ENERGY_REL,
    IMPACT_LEAD_S,
    POSITION_BOUND_M,
    RETENSION_WINDOW_S,
    SLACK_GAP_M,
    STRAY_M,
    TAUT_GAP_M,
    cable_dampratio,
)

MEASURES = [("max_position_diff_m", "position difference (m)"), ("slack_mismatch_steps", "slack/taut mismatch (steps)"),
            ("max_slack_stretch_m", "slack cable stretch (m)"), ("max_energy_ratio", "|energy residual| / bound"),
            ("max_impact_energy_ratio", "impact energy difference / bound")]



def report(rows: list[dict], wall_s: float, workers: int, mujoco_timestep: float) -> str:
    """Markdown: the verdict, the figures per spec, the worst case of each measure with its replay."""
    import datetime
    import platform

    failed = [r for r in rows if not r["passed"]]
    confirming = " s, then ".join(f"{step:g}" for step in CONFIRM_TIMESTEPS) + " s"
    damping = ", ".join(f"{cable_dampratio(step):.3g} at {step:g} s" for step in CONFIRM_TIMESTEPS)
    only_at = {step: sum(bool(r["first_status"]) and r["passed"] and float(r["mujoco_timestep"]) == step for r in rows)
               for step in CONFIRM_TIMESTEPS}
    confirmed = ", ".join(f"{count} of them only with MuJoCo at {step:g} s" for step, count in only_at.items())
    lines = [f"# Plant fuzzing: {len(rows)} open-loop experiments, own plant against MuJoCo", "",
             f"{datetime.date.today().isoformat()}, {platform.node()} ({platform.machine()}, "
             f"{platform.python_version()}), {workers} worker(s), {wall_s:.0f} s wall; MuJoCo step "
             f"{mujoco_timestep:g} s (a disagreement confirmed at {confirming}), cable limits' damping "
             f"ratio {cable_dampratio(mujoco_timestep):.3g} ({damping}). Bounds: positions "
             f"{POSITION_BOUND_M * 1e6:g} µm outside "
             f"±{RETENSION_WINDOW_S * 1e3:g} ms of re-tensions; no cable clearly slack (gap < "
             f"−{SLACK_GAP_M * 1e6:g} µm) in one plant and clearly taut (gap > −{TAUT_GAP_M * 1e6:g} µm) in the "
             f"other, outside ±1 plant step of the own plant's transitions and {RETENSION_WINDOW_S * 1e3:g} ms after "
             "a re-tension; the kinetic energy each impact takes (the own plant's T⁺ − T⁻ against the work of "
             f"MuJoCo's constraint forces from {IMPACT_BEFORE_S * 1e3:g} ms before to {RETENSION_WINDOW_S * 1e3:g} ms "
             f"after it, MuJoCo restarted from the own plant's state {IMPACT_LEAD_S * 1e3:g} ms before; a cascade "
             f"is one impact) within {IMPACT_ENERGY_REL:.0%} or {IMPACT_ENERGY_J:g} J (where only that is off at "
             "the finest step, MuJoCo's figure extrapolated to step 0 from its two finest, if they show it "
             "converging on the own plant's at first order); the own plant's invariants (acroboter.sim.plant).", "",
             f"**{len(rows) - len(failed)} of {len(rows)} agree** ({confirmed}); {len(failed)} fail.", "",
             f"Coverage: {sum(r['compared_s'] for r in rows):.0f} s compared of "
             f"{sum(r['duration'] for r in rows):.0f} s drawn; {sum(not r['left'] for r in rows)} cases compared "
             "to their end, the others up to where they left "
             f"sensible motion (a body {STRAY_M} m from its start or a cable {STRAY_M} m slack: "
             f"{sum(bool(r['left']) for r in rows)}); {sum(r['retensions'] for r in rows)} re-tensions and "
             f"{sum(r['transitions'] for r in rows)} slack/taut transitions of the own plant in all, in "
             f"{sum(r['retensions'] > 0 for r in rows)} cases.", "",
             "| spec | cases | failed | compared (s) | re-tensions | worst position difference (µm) "
             "| worst energy ratio | impacts compared | worst impact energy difference / bound |",
             "|---|---|---|---|---|---|---|---|---|"]
    for spec in sorted({r["spec"] for r in rows}):
        mine = [r for r in rows if r["spec"] == spec]
        lines.append(f"| {spec} | {len(mine)} | {sum(not r['passed'] for r in mine)} | "
                     f"{sum(r['compared_s'] for r in mine):.0f} | {sum(r['retensions'] for r in mine)} | "
                     f"{max(r['max_position_diff_m'] for r in mine) * 1e6:.2f} | "
                     f"{max(r['max_energy_ratio'] for r in mine):.2e} | {sum(r.get('impacts', 0) for r in mine)} | "
                     f"{max(r.get('max_impact_energy_ratio', 0.0) for r in mine):.3g} |")
    lines += ["", "## The worst case of each measure", ""]
    for key, label in MEASURES:
        if key not in rows[0]:
            continue  # a CSV from before the measure
        worst = max(rows, key=lambda r: r[key])
        lines.append(f"- {label}: {worst[key]:.3g} ({worst['spec']}, seed {worst['seed']}, {worst['status']}): "
                     f"`{worst['replay']}`")
    if failed:
        lines += ["", "## Failed cases", ""]
        lines += [f"- {r['spec']} seed {r['seed']}: {r['status']}"
                  + (f" (worst difference by MuJoCo step: {r['position_diff_by_step']})"
                     if r.get("position_diff_by_step") else "") + f" — `{r['replay']}`" for r in failed[:50]]
    needed = [r for r in rows if r.get("position_diff_by_step") and r["passed"]]
    if needed:
        lines += ["", "## Cases that agree only at a finer MuJoCo step (the worst body difference at each step)", ""]
        lines += [f"- {r['spec']} seed {r['seed']}: {r['position_diff_by_step']}" for r in needed[:60]]
    return "\n".join(lines) + "\n"
