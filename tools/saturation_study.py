"""The saturation strategies side by side (docs/saturation.md): every scenario of acroboter.studies.saturation,
MLM, Penalty and Iterative Penalty (3), QP against underactuation. Writes into docs/saturation/ (or --out):
results.csv (one row per run), results.json (the rows with the date, machine and versions) and errors.png
(position error and winch tensions over time, the two strategies overlaid).

    .venv/bin/python tools/saturation_study.py [--out docs/saturation] [--methods mlm,penalty,iterative-3]
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/saturation"))
    parser.add_argument("--methods", default="mlm,penalty,iterative-3")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from acroboter.studies.saturation import SCENARIOS, run_scenario

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    args.out.mkdir(parents=True, exist_ok=True)
    rows, runs = [], {}
    for scenario in SCENARIOS:
        measures, results = run_scenario(scenario, methods)
        rows += [m.row() for m in measures]
        runs[scenario.name] = results
        for m in measures:
            print(f"{m.scenario:32s} {m.method:12s} {m.strategy:15s} max {m.max_position_error_mm:8.3f} mm "
                  f"rms {m.rms_position_error_mm:7.3f} mm tilt {m.max_tilt_deg:.3f} deg on limits "
                  f"{m.time_on_limits_s:6.2f} s ({m.limit_episodes} episodes) beyond {m.worst_beyond_limits:.1e}",
                  file=sys.stderr)
    with open(args.out / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    import casadi
    import scipy

    meta = {"date": datetime.date.today().isoformat(), "machine": platform.node(), "cpu": cpu_name(),
            "python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "casadi": casadi.__version__, "rows": rows}
    (args.out / "results.json").write_text(json.dumps(meta, indent=1) + "\n")

    shown = [m for m in ("mlm", "penalty") if m in methods] or methods[:1]
    fig, axes = plt.subplots(2, len(SCENARIOS), figsize=(5.2 * len(SCENARIOS), 6.4), sharex=True, squeeze=False)
    styles = {"qp": "-", "underactuation": "--"}
    for col, scenario in enumerate(SCENARIOS):
        results = runs[scenario.name]
        for method in shown:
            for strategy in ("qp", "underactuation"):
                r = results[(method, strategy)]
                axes[0, col].plot(r.time, r.position_error_mm, styles[strategy], lw=0.9,
                                  label=f"{method}, {strategy}")
                tension = r.u[:, 0]
                axes[1, col].plot(r.time, tension, styles[strategy], lw=0.9, label=f"{method}, {strategy}")
        axes[0, col].set_title(scenario.name, fontsize=10)
        axes[0, col].set_yscale("log")
        axes[0, col].set_ylim(1e-3, None)
        axes[1, col].axhline(scenario.upper, color="k", lw=0.6, ls=":")
        axes[1, col].set_xlabel("t (s)")
    axes[0, 0].set_ylabel("position error (mm)")
    axes[1, 0].set_ylabel("tension_1 (N), limit dotted")
    axes[0, -1].legend(fontsize=7)
    fig.suptitle(f"QP (solid) against underactuation (dashed), {meta['date']}, {meta['machine']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(args.out / "errors.png", dpi=110)
    print(f"wrote {args.out}/results.csv, results.json, errors.png", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
