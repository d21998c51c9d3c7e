"""Paths nobody planned (acroboter.studies.generated_paths): N random two- and three-edge paths, alternately on the
default and the four-cable crane, with winch limits drawn where the statics leave 5-20 % of the span, each planned
with `plan --tolerance 0.1mm` and flown by MLM, Penalty and Iterative Penalty (3) with the limits applied. Path i is
drawn from seed + i: `--paths 1 --seed K` plans path K again.

Writes into --out (default results/plan_fuzz; the folder is replaced as a whole when the run ends, never mixed with
an earlier run's files): paths.csv (a row per path, units in the column names), report.md (every path, what fails
and the command that replays it), results.json (the rows with the date, machine and versions) and, per path,
<name>/spec.toml and <name>/plan.csv.

    .venv/bin/python tools/plan_fuzz.py [--paths 20] [--seed 0] [--workers 2] [--out results/plan_fuzz]
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import platform
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from saturation_study import cpu_name  # noqa: E402

MARKER = ".plan-fuzz"  # a folder this tool wrote (it may replace it)
COLUMNS = ("name", "spec", "edges", "yaw_deg", "static_room", "winch_upper_N", "static_largest_N", "planned_s",
           "time_optimal_s", "time_optimal_flown_mm", "uniform_s", "flown_mm", "mlm_mm", "penalty_mm",
           "iterative-3_mm", "saturated_s", "margin_achieved", "rounds", "plan_s", "passes")


def one(seed: int, folder: str, tolerance: float, margin: float, intervals: int) -> dict:
    """Path `seed` drawn, planned and judged (in a worker process): its row."""
    from acroboter.model.crane_generator import RandomDraw
    from acroboter.studies.generated_paths import SPECS, drawn_path, run_path

    spec = SPECS[seed % len(SPECS)]
    name = f"path_{seed}"
    path = drawn_path(RandomDraw(seed), spec)
    started = time.perf_counter()
    result = run_path(path, name, Path(folder) / name, tolerance, margin, intervals)
    row = result.row()
    row["wall_s"] = time.perf_counter() - started
    row["seed"] = seed
    return row


def table_row(r: dict) -> dict:
    flights = r["flights"]
    return {"name": r["name"], "spec": r["spec"], "edges": r["edges"], "yaw_deg": round(r["yaw_deg"], 2),
            "static_room": round(r["static_room"], 4), "winch_upper_N": round(r["winch_limits"][1], 4),
            "static_largest_N": round(r["static_tensions"][1], 4), "planned_s": r["planned_s"],
            "time_optimal_s": r["time_optimal_s"], "time_optimal_flown_mm": r["time_optimal_flown_mm"],
            "uniform_s": r["uniform_s"], "flown_mm": r["flown_mm"],
            **{f"{m}_mm": flights.get(m, {}).get("max_position_error_mm") for m in ("mlm", "penalty", "iterative-3")},
            "saturated_s": max((f.get("saturated_s", 0.0) for f in flights.values()), default=None),
            "margin_achieved": r["margin_achieved"], "rounds": r["rounds"], "plan_s": round(r["plan_s"], 1),
            "passes": not r["failures"]}


def figure(value, digits: int = 4) -> str:
    return "–" if value is None else f"{value:.{digits}g}"


def report(rows: list[dict], meta: dict) -> str:
    passing = sum(1 for r in rows if not r["failures"])
    lines = [f"# Paths nobody planned: {passing} of {len(rows)} pass", "",
             f"{meta['date']}, {meta['machine']} ({meta['cpu']}), {meta['workers']} worker(s), {meta['wall_s']:.0f} s "
             f"wall; tolerance {1e3 * meta['tolerance']:g} mm, margin {100 * meta['margin']:g} %, "
             f"{meta['intervals']} intervals; CasADi {meta['casadi']}.", "",
             "Each path passes when every method flies it within the tolerance at every clock phase, no flight has an "
             "instant on a limit, no planned input is beyond the limits less the margin on the 1 ms grid, and it is "
             "faster than the best uniform slowdown of the time-optimal timing that meets the same tolerance.", "",
             "| path | crane | edges | yaw ° | static room | upper N | time-optimal s (flown mm) | uniform s | "
             "planned s | flown mm (MLM / penalty / IP-3) | rounds | plan s | passes |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        t = table_row(r)
        optimal = f"{figure(t['time_optimal_s'])} ({figure(t['time_optimal_flown_mm'], 3)})"
        lines.append(f"| {t['name']} | {t['spec']} | {t['edges']} | {t['yaw_deg']:.1f} | "
                     f"{100 * t['static_room']:.1f} % | {t['winch_upper_N']:.3f} | {optimal} "
                     f"| {figure(t['uniform_s'])} | {figure(t['planned_s'])} | {figure(t['mlm_mm'], 3)} / "
                     f"{figure(t['penalty_mm'], 3)} / {figure(t['iterative-3_mm'], 3)} | {t['rounds']} | "
                     f"{t['plan_s']:.0f} | {'yes' if t['passes'] else 'no'} |")
    failing = [r for r in rows if r["failures"]]
    if failing:
        lines += ["", "## What fails", ""]
        for r in failing:
            lines.append(f"- **{r['name']}** ({r['spec']}): {'; '.join(r['failures'])}. Replay: "
                         f"`.venv/bin/python tools/plan_fuzz.py --paths 1 --seed {r['seed']} --out "
                         f"results/plan_fuzz_{r['name']}`")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paths", type=int, default=20, help="how many paths (path i drawn from seed + i)")
    parser.add_argument("--seed", type=int, default=0, help="the first path's seed")
    parser.add_argument("--workers", type=int, default=2, help="processes planning paths side by side")
    parser.add_argument("--tolerance", type=float, default=1e-4, help="position error the plans must meet (m)")
    parser.add_argument("--margin", type=float, default=0.02, help="of each limit span, kept free by the plan")
    parser.add_argument("--intervals", type=int, default=12, help="the plan's intervals (at least 6 per edge)")
    parser.add_argument("--out", type=Path, default=Path("results/plan_fuzz"), help="output folder")
    args = parser.parse_args(argv)
    if args.paths < 1 or args.workers < 1:
        parser.error("--paths and --workers: at least 1")
    if args.out.exists() and not (args.out / MARKER).exists():
        parser.error(f"--out {args.out} exists and was not written by this tool: choose another folder")
    staging = args.out.with_name(args.out.name + ".partial")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    started = time.perf_counter()
    seeds = range(args.seed, args.seed + args.paths)
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(one, s, str(staging), args.tolerance, args.margin, args.intervals) for s in seeds]
        rows = []
        for future in futures:
            rows.append(future.result())
            r = rows[-1]
            verdict = "passes" if not r["failures"] else "FAILS: " + "; ".join(r["failures"])
            print(f"{r['name']} ({r['spec']}, {r['edges']} edges): planned {figure(r['planned_s'])} s, flown "
                  f"{figure(r['flown_mm'], 3)} mm, {verdict} ({r['wall_s']:.0f} s)", file=sys.stderr, flush=True)
    import casadi
    import numpy as np

    meta = {"date": datetime.date.today().isoformat(), "machine": platform.node(), "cpu": cpu_name(),
            "python": platform.python_version(), "numpy": np.__version__, "casadi": casadi.__version__,
            "workers": args.workers, "wall_s": time.perf_counter() - started, "tolerance": args.tolerance,
            "margin": args.margin, "intervals": args.intervals, "paths": rows}
    (staging / "results.json").write_text(json.dumps(meta, indent=1) + "\n")
    with open(staging / "paths.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(COLUMNS))
        writer.writeheader()
        writer.writerows(table_row(r) for r in rows)
    (staging / "report.md").write_text(report(rows, meta))
    (staging / MARKER).write_text("written by tools/plan_fuzz.py\n")
    shutil.rmtree(args.out, ignore_errors=True)  # this tool's earlier run (MARKER): replaced as a whole
    staging.rename(args.out)
    print(f"wrote {args.out}/report.md, paths.csv, results.json", file=sys.stderr)
    return 0 if all(not r["failures"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
