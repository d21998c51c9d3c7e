"""How fast can the paper's path be flown? Every case of acroboter.studies.planned_flights (the default and the
four-cable crane, winch limits [5, 30], [5, 60], [5, 120] N): the retiming's plan and MLM, Penalty and Iterative
Penalty (3) flying it. Writes into docs/planning/ (or --out): results.csv (one row per case and method),
results.json (the cases with the date, machine and versions) and speed.png (the planned path fraction s(t)
against the path's own timing, and the tracked point's planned speed).

    .venv/bin/python tools/retiming_study.py [--out docs/planning] [--cases 0,1,2] [--intervals 120] [--assemble]
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from saturation_study import cpu_name  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/planning"))
    parser.add_argument("--cases", default="", help="indices into CASES, comma-separated (default: all)")
    parser.add_argument("--intervals", type=int, default=120)
    parser.add_argument("--margin", type=float, default=0.05)
    parser.add_argument("--assemble", action="store_true", help="only gather the case files already in --out")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from acroboter.planning.ideal_motion import PlanningError
    from acroboter.studies.planned_flights import CASES, run_case

    chosen = [CASES[int(i)] for i in args.cases.split(",") if i.strip()] or list(CASES)
    if args.assemble:
        chosen = []
    args.out.mkdir(parents=True, exist_ok=True)
    for case in chosen:  # each case into its own file: cases can run in parallel processes (--cases)
        print(f"{case.name}: planning ...", file=sys.stderr, flush=True)
        stem = f"case-{case.spec}-{case.lower:g}-{case.upper:g}"
        try:
            result, plan, _ = run_case(case, args.out / "specs", args.margin, args.intervals)
        except PlanningError as err:
            print(f"{case.name}: no plan: {err}", file=sys.stderr)
            (args.out / f"{stem}.json").write_text(json.dumps({"case": case.name, "error": str(err)}, indent=1))
            continue
        print(f"{case.name}: planned {result.planned_s:.3f} s (own {result.path_own_s:.1f} s, uniform "
              f"{result.uniform_s:.3f} s, edge-wise slowdown {result.edge_wise_s}) in {result.plan_solve_s:.0f} s",
              file=sys.stderr, flush=True)
        for run in result.runs:
            print(f"   {run['method']:12s} max {run['max_position_error_mm']:8.3f} mm, yaw "
                  f"{run['max_yaw_error_deg']:.4f} deg, on limits {run['time_on_limits_s']:.2f} s, beyond "
                  f"{run['worst_beyond_limits']:.1e}", file=sys.stderr, flush=True)
        traj = plan.trajectory
        keep = np.unique(np.linspace(0, traj.times.size - 1, min(traj.times.size, 3000)).astype(int))
        series = {"times": plan.times.tolist(), "s": plan.s.tolist(), "trajectory_t": traj.times[keep].tolist(),
                  "speed": np.linalg.norm(traj.velocity[keep, :3], axis=1).tolist()}
        (args.out / f"{stem}.json").write_text(json.dumps({**result.row(), "series": series}, indent=1) + "\n")
    assemble(args, plt)
    return 0


def assemble(args, plt) -> None:
    """results.csv, results.json and speed.png from every case file in the folder."""
    import casadi
    import scipy

    cases = [json.loads(f.read_text()) for f in sorted(args.out.glob("case-*.json"))]
    rows = [{"case": c["case"], "planned_s": c["planned_s"], **run} for c in cases if "runs" in c for run in c["runs"]]
    if rows:
        with open(args.out / "results.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    meta = {"date": datetime.date.today().isoformat(), "machine": platform.node(), "cpu": cpu_name(),
            "python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "casadi": casadi.__version__, "intervals": args.intervals,
            "cases": [{k: v for k, v in c.items() if k != "series"} for c in cases]}
    (args.out / "results.json").write_text(json.dumps(meta, indent=1) + "\n")
    planned = [c for c in cases if "series" in c]
    if planned:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
        for c in planned:
            label = f"{c['case']}, margin {100 * c['margin']:g} %"
            axes[0].plot(c["series"]["times"], c["series"]["s"], lw=1.0, label=label)
            axes[1].plot(c["series"]["trajectory_t"], c["series"]["speed"], lw=0.8, label=label)
        own = planned[0]["path_own_s"]
        axes[0].plot([0, own], [0, 1], "k:", lw=0.8, label=f"the path's own timing ({own:.0f} s), as a line")
        axes[0].set_xlabel("t (s)")
        axes[0].set_ylabel("fraction of the path s")
        axes[1].set_xlabel("t (s)")
        axes[1].set_ylabel("planned speed of the tracked point (m/s)")
        axes[0].legend(fontsize=7)
        fig.suptitle(f"planned timings, every edge rest to rest, {meta['date']}, {meta['machine']}", fontsize=10)
        fig.tight_layout()
        fig.savefig(args.out / "speed.png", dpi=110)
    print(f"wrote {args.out}/results.csv, results.json, speed.png", file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
