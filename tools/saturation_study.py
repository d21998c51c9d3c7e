"""The saturation strategies side by side (docs/saturation.md): every scenario of acroboter.studies.saturation,
MLM, Penalty and Iterative Penalty (3), QP against underactuation. Writes into docs/saturation/ (or --out):
results.csv (one row per run), results.json (the rows with the date, machine and versions, and the plan of the
planned scenarios) and errors.png (position error and the largest winch tension over time, the two strategies overlaid);
prints the table rows of docs/saturation.md on stdout. The planned trajectory is cached in --plans (default
--out) as plan-<key>.csv (what `acroboter run --trajectory` reads) and .json (the plan's summary), keyed by what
it is computed from (acroboter.studies.saturation.plan_key): a new spec, margin or grid plans anew.

    .venv/bin/python tools/saturation_study.py [--out docs/saturation] [--methods mlm,penalty,iterative-3]
        [--plans DIR (default: --out)] [--only SUBSTRING]
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import platform
import sys
from pathlib import Path

import numpy as np


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def seconds(value, missing: str = "not recovered") -> str:
    return missing if value is None else f"{value:.2f}"


def table_row(r: dict) -> str:
    """One row of docs/saturation.md's table."""
    episodes = r["limit_episodes"]
    per_episode = (f"{seconds(r['recovery_median_s'])} / {seconds(r['recovery_worst_s'], 'none recovered')}"
                   if episodes else "–")
    cells = [r["scenario"], r["method"], r["strategy"], f"{r['max_position_error_mm']:.2f}",
             f"{r['rms_position_error_mm']:.3f}", f"{r['max_yaw_error_deg']:.4f}", f"{r['max_tilt_deg']:.3f}",
             f"{r['time_on_limits_s']:.2f} ({episodes})", seconds(r["last_on_limit_s"], "–"),
             seconds(r["recovery_s"]) if episodes else "–", per_episode,
             f"{r['episodes_not_recovered']}/{episodes}", f"{r['worst_beyond_limits']:.3g}",
             seconds(r["diverged_at"], "–")]
    return "| " + " | ".join(cells) + " |"


def path_row(r: dict) -> str:
    """One row of docs/saturation.md's table of the planned scenarios: on the path and after its end."""
    cells = [r["scenario"], r["method"], r["strategy"], f"{r['path_end_s']:.3f}",
             f"{r['max_position_error_on_path_mm']:.2f}", str(r["episodes_on_path"]),
             str(r["limit_episodes"] - r["episodes_on_path"]), seconds(r["diverged_at"], "–")]
    return "| " + " | ".join(cells) + " |"


def unlimited_row(u: dict) -> str:
    """One row of docs/saturation.md's table of the planned flights with the limits removed."""
    def number(v, fmt):
        return "–" if v is None else format(v, fmt)

    cells = [u["scenario"], u["method"], f"{u['min_winch_on_path_n']:.2f}..{u['max_winch_on_path_n']:.2f}",
             number(u["max_winch_after_n"], ".2f"), number(u["first_beyond_upper_s"], ".2f"),
             f"{u['max_position_error_on_path_mm']:.2f}", number(u["max_position_error_after_mm"], ".2f"),
             f"{u['end_position_error_mm']:.3f}", seconds(u["diverged_at"], "–")]
    return "| " + " | ".join(cells) + " |"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/saturation"))
    parser.add_argument("--methods", default="mlm,penalty,iterative-3")
    parser.add_argument("--plans", type=Path, default=None,
                        help="where the planned trajectories are cached (default: --out)")
    parser.add_argument("--only", default=None, help="only the scenarios whose name contains this (a trial run)")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")

    from acroboter.studies.saturation import SCENARIOS, run_scenario

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    scenarios = [s for s in SCENARIOS if args.only is None or args.only in s.name]
    args.out.mkdir(parents=True, exist_ok=True)
    rows, runs, plans, unlimited = [], {}, {}, []
    for scenario in scenarios:
        measures, results, extra = run_scenario(scenario, methods, plans=args.plans or args.out)
        rows += [m.row() for m in measures]
        runs[scenario.name] = results
        if extra is not None:
            plans[extra["plan"]["key"]] = extra["plan"]
            unlimited += extra["unlimited"]
        for m in measures:
            print(f"{m.scenario:32s} {m.method:12s} {m.strategy:15s} max {m.max_position_error_mm:8.3f} mm "
                  f"rms {m.rms_position_error_mm:7.3f} mm tilt {m.max_tilt_deg:.3f} deg on limits "
                  f"{m.time_on_limits_s:6.2f} s ({m.limit_episodes} episodes) beyond {m.worst_beyond_limits:.1e} "
                  f"wall {m.wall_s:.1f} s", file=sys.stderr)
    meta = write_results(args.out, rows, scenarios, plans, unlimited)
    write_figure(args.out / "errors.png", scenarios, runs, rows, methods, meta)
    print(f"wrote {args.out}/results.csv, results.json, errors.png", file=sys.stderr)
    return 0


def write_results(out: Path, rows: list[dict], scenarios, plans: dict, unlimited: list) -> dict:
    """results.csv and results.json (with the machine and versions), the tables printed; the JSON's content."""
    import casadi
    import scipy

    with open(out / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows([{**r, "divergence": (r["divergence"] or "")[:80],
                           "episode_recoveries_s": " ".join("-" if v is None else f"{v:.3f}"
                                                            for v in r["episode_recoveries_s"])} for r in rows])
    for r in rows:
        print(table_row(r))
    print()
    planned = {s.name for s in scenarios if s.speedup is not None}
    for r in rows:
        if r["scenario"] in planned:
            print(path_row(r))
    print()
    for u in unlimited:
        print(unlimited_row(u))
    meta = {"date": datetime.date.today().isoformat(), "machine": platform.node(), "cpu": cpu_name(),
            "python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "casadi": casadi.__version__, "rows": rows, "plans": list(plans.values()),
            "unlimited": unlimited}
    (out / "results.json").write_text(json.dumps(meta, indent=1) + "\n")
    return meta


def write_figure(path: Path, scenarios, runs: dict, rows: list[dict], methods: list[str], meta: dict) -> None:
    """Per scenario the position error and the largest winch tension over time, QP against underactuation."""
    import matplotlib.pyplot as plt

    shown = [m for m in ("mlm", "penalty") if m in methods] or methods[:1]
    cols = min(3, len(scenarios))
    blocks = -(-len(scenarios) // cols)
    fig, axes = plt.subplots(2 * blocks, cols, figsize=(5.2 * cols, 6.4 * blocks), squeeze=False)
    styles = {"qp": "-", "underactuation": "--"}
    for i, scenario in enumerate(scenarios):
        results = runs[scenario.name]
        top, bottom = axes[2 * (i // cols), i % cols], axes[2 * (i // cols) + 1, i % cols]
        bottom.sharex(top)
        for method in shown:
            for strategy in ("qp", "underactuation"):
                r = results[(method, strategy)]
                top.plot(r.time, r.position_error_mm, styles[strategy], lw=0.9, label=f"{method}, {strategy}")
                winches = [k for k, name in enumerate(r.layout.inputs) if name.startswith("tension")]
                bottom.plot(r.time, r.u[:, winches].max(axis=1), styles[strategy], lw=0.9,
                            label=f"{method}, {strategy}")
        top.set_title(scenario.name, fontsize=10)
        top.set_yscale("log")
        top.set_ylim(1e-3, None)
        bottom.axhline(scenario.upper, color="k", lw=0.6, ls=":")
        ends = {r["path_end_s"] for r in rows if r["scenario"] == scenario.name and r["path_end_s"] < r["duration_s"]}
        for end in ends if scenario.speedup is not None else ():
            top.axvline(end, color="k", lw=0.6, ls="-.")
            bottom.axvline(end, color="k", lw=0.6, ls="-.")
        bottom.set_xlabel("t (s)")
        if i % cols == 0:
            top.set_ylabel("position error (mm)")
            bottom.set_ylabel("largest winch tension (N), limit dotted")
    for j in range(len(scenarios), blocks * cols):
        axes[2 * (j // cols), j % cols].axis("off")
        axes[2 * (j // cols) + 1, j % cols].axis("off")
    axes[0, cols - 1].legend(fontsize=7)
    fig.suptitle(f"QP (solid) against underactuation (dashed); a planned path's end dash-dotted; {meta['date']}, "
                 f"{meta['machine']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
