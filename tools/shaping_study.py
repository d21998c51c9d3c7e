"""Input shaping against the time-optimal plan on the paper's path: every case of acroboter.studies.planned_flights
(the default and the four-cable crane, winch limits [5, 30], [5, 60], [5, 120] N, margin 5 %) planned with
`plan(shaper=...)` for ZV, ZVD and unshaped edges (acroboter.planning.shaping), each flown by MLM, Penalty and
Iterative Penalty (3) with the limits applied (the plan's certificate). The time-optimal rest-to-rest plans of the
same cases are docs/planning/results.csv (tools/retiming_study.py). Writes docs/planning/shaping.csv (one row per
case and shaper) and shaping.json (the date, machine and versions).

    .venv/bin/python tools/shaping_study.py [--out docs/planning] [--cases 0,1,2] [--assemble]
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from saturation_study import cpu_name  # noqa: E402

SHAPED = ("zv", "zvd", "unshaped")
METHODS = ("mlm", "penalty", "iterative-3")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/planning"))
    parser.add_argument("--cases", default="", help="indices into CASES, comma-separated (default: all)")
    parser.add_argument("--margin", type=float, default=0.05)
    parser.add_argument("--assemble", action="store_true", help="only gather the case files already in --out")
    args = parser.parse_args(argv)
    from acroboter.api.crane import Crane
    from acroboter.model.spec_edits import with_winch_limits
    from acroboter.planning.ideal_motion import PlanningError
    from acroboter.process.locations import example_spec
    from acroboter.studies.planned_flights import CASES

    chosen = [] if args.assemble else ([CASES[int(i)] for i in args.cases.split(",") if i.strip()] or list(CASES))
    args.out.mkdir(parents=True, exist_ok=True)
    specs = Path(tempfile.mkdtemp(prefix="shaping-specs-"))
    for case in chosen:  # each case into its own file: cases can run in parallel processes (--cases)
        spec_path = specs / f"{case.spec}_{case.lower:g}_{case.upper:g}.toml"
        spec_path.write_text(with_winch_limits(example_spec(case.spec).read_text(), case.upper, case.lower))
        crane = Crane.from_toml(spec_path)
        rows = []
        for kind in SHAPED:
            started = time.perf_counter()
            row = {"case": case.name, "shaper": kind}
            try:
                plan = crane.plan(margin=args.margin, shaper=kind, certify=list(METHODS))
            except PlanningError as err:
                plan = getattr(err, "plan", None)
                row["failure"] = str(err)
            row["plan_and_flights_s"] = time.perf_counter() - started
            if plan is not None:
                row.update(shaped_row(plan))
            print(json.dumps(row), file=sys.stderr, flush=True)
            rows.append(row)
        stem = f"shaping-{case.spec}-{case.lower:g}-{case.upper:g}"
        (args.out / f"{stem}.json").write_text(json.dumps(rows, indent=1) + "\n")
    assemble(args.out)
    return 0


def shaped_row(plan) -> dict:
    """A shaped plan's figures: duration, the swing left at the corners, each method's flown error."""
    swing = plan.corner_swing
    row = {"duration_s": plan.duration, "path_own_s": plan.path_duration, "uniform_s": plan.uniform_duration,
           "status": plan.status, "margin_planned": plan.margin_achieved,
           "corner_swing_max_mm": max(c["displacement_mm"] for c in swing),
           "corner_speed_max_mm_s": max(c["speed_mm_s"] for c in swing),
           "modes_s": [[m["period_s"] for m in e["modes"]] for e in plan.shaping["edges"]],
           "edge_factors": [e["factor"] for e in plan.shaping["edges"]]}
    if plan.certificate is not None:
        for method, flight in plan.certificate.flights.items():
            row[f"{method}_error_mm"] = flight["max_position_error_mm"]
            row[f"{method}_saturated_s"] = flight["saturated_s"]
        row["margin_flown"] = plan.certificate.margin_achieved
    return row


def assemble(out: Path) -> None:
    """shaping.csv and shaping.json from every case file in the folder."""
    import casadi
    import numpy
    import scipy

    rows = [r for f in sorted(out.glob("shaping-*.json")) for r in json.loads(f.read_text())]
    if rows:
        fields = list(dict.fromkeys(k for r in rows for k in r if k not in ("modes_s", "edge_factors")))
        with open(out / "shaping.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
    meta = {"date": datetime.date.today().isoformat(), "machine": platform.node(), "cpu": cpu_name(),
            "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__,
            "casadi": casadi.__version__, "rows": rows}
    (out / "shaping.json").write_text(json.dumps(meta, indent=1) + "\n")
    print(f"wrote {out}/shaping.csv, shaping.json", file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
