"""What the penalty formulation buys you: `python -m acroboter.study [redundant|noncollocated|all]`.

- redundant: the default crane, the same crane with redundant geometric constraints (w = u × v on
  both bodies) and with a redundant task (yaw twice), under MLM, Penalty and Iterative Penalty.
- noncollocated: the four-input crane (three winches and the yaw torque, task XYZ and yaw) under
  MLM and the penalty methods with every input recovery (projected, kinetic, eq12, eq13, eq15, κ = 0, 0.5,
  1):
  which track, which drift, which diverge and when.

Writes a Markdown table, summary.json and figures per study into --out (default results/study).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..model.ranges import STUDY_DURATION
from ..model.spec import MAX_CONTROL_STEPS
from ..report.study_figures import case_label, position_error_figure
from ..studies.formulations import noncollocated_cases, redundant_cases, study_noncollocated, study_redundant
from .entry import guarded, progress_disabled, ranged
from .outputs import ResultsFolder, out_path, results_folder

# The study's cranes run at 50 Hz: the record cap in seconds.
STUDY_RATE_HZ = 50.0
STUDY_MAX_DURATION_S = MAX_CONTROL_STEPS / STUDY_RATE_HZ  # STUDY_DURATION's bound (acroboter.model.ranges)


def markdown_table(cases: list[dict], with_spec: bool) -> str:
    head = ("| " + ("spec | " if with_spec else "") + "method | outcome | max pos. error [mm] | rms [mm] | "
            "max yaw error [°] | max tilt [°] | max \\|φ\\| | min winch tension [N] |")
    columns = 8 + (1 if with_spec else 0)
    lines = [head, "|" + "---|" * columns]
    for c in cases:
        first = (f"| {c['spec']} | " if with_spec else "| ") + f"{case_label(c)} | "
        if c["outcome"] == "refused":
            lines.append(first + f"refused: {c['message'].split(':')[0]} | – | – | – | – | – | – |")
            continue
        s = c["summary"]
        outcome = c["outcome"] if c["diverged_at_s"] is None else f"diverged at {c['diverged_at_s']:.2f} s"
        yaw = f"{s['max_yaw_error_deg']:.4f}" if s["max_yaw_error_deg"] is not None else "–"
        # None: the state blew up between two records, the error at divergence is unbounded
        pos, rms = ((f"{s['max_position_error_mm']:.4g}", f"{s['rms_position_error_mm']:.4g}")
                    if s["max_position_error_mm"] is not None else ("unbounded", "–"))
        lines.append(first + f"{outcome} | {pos} | {rms} | "
                     f"{yaw} | {s['max_tilt_deg']:.3g} | {s['max_constraint_violation']:.1e} | "
                     f"{s['min_winch_tension_N']:.4g} |")
    return "\n".join(lines)


def _write(out: Path, name: str, cases: list[dict], title: str, with_spec: bool) -> str:
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    table = markdown_table(cases, with_spec)
    (folder / "table.md").write_text(table + "\n")
    brief = [{k: v for k, v in c.items() if k not in ("t", "position_error_mm", "winch_min_N")} for c in cases]
    (folder / "summary.json").write_text(json.dumps(brief, indent=2) + "\n")
    position_error_figure(cases, folder / "position_error.png", title, with_spec)
    return table


@guarded
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="acroboter study", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("which", nargs="?", choices=["redundant", "noncollocated", "all"], default="all",
                        help="which study to run (default: %(default)s)")
    parser.add_argument("--duration", type=ranged(STUDY_DURATION), default=None,
                        help=f"simulated seconds, at most {STUDY_MAX_DURATION_S:g} (default: the whole path)")
    parser.add_argument("--out", type=out_path, default=Path("results/study"),
                        help="output folder (default: %(default)s)")
    args = parser.parse_args(argv)
    if args.duration is not None and round(args.duration * STUDY_RATE_HZ) < 1:
        parser.error(f"--duration {args.duration:g} s is no control step at {STUDY_RATE_HZ:g} Hz: give at least "
                     f"{1 / STUDY_RATE_HZ:g} s")
    studies = [s for s in ("redundant", "noncollocated") if args.which in (s, "all")]
    expected = [f"{s}/{name}" for s in studies for name in ("table.md", "summary.json", "position_error.png")]
    # each study's folder is its own (accumulate): `study noncollocated` keeps redundant/, which it did not redo
    with results_folder(args.out, "study", expected=expected, accumulate=True) as folder:  # checked before any work
        return _study(args, folder)


def _study(args: argparse.Namespace, folder: ResultsFolder) -> int:
    from tqdm import tqdm

    from ..model.spec import SpecError
    from ..runtime.compiled import StaleModelError

    total = (len(redundant_cases()) if args.which in ("redundant", "all") else 0) + (
        len(noncollocated_cases()) if args.which in ("noncollocated", "all") else 0)
    try:
        with tqdm(total=total, unit="run", file=sys.stderr, disable=progress_disabled()) as bar:
            if args.which in ("redundant", "all"):
                cases = study_redundant(args.duration, bar.update)
                print("## Redundant constraints and a redundant task\n")
                print(_write(folder.staging, "redundant", cases, "Redundant constraints and task: position error",
                             with_spec=True))
            if args.which in ("noncollocated", "all"):
                cases = study_noncollocated(args.duration, bar.update)
                print("\n## Non-collocated four-input crane\n")
                print(_write(folder.staging, "noncollocated", cases, "Four inputs (non-collocated): position error",
                             with_spec=False))
    except (SpecError, StaleModelError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    folder.publish()
    print(f"\nresults in {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
