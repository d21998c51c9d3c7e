"""`acroboter plant-fuzz` (`make plant-fuzz`, `python -m acroboter.plant_fuzz`): many generated open-loop
experiments on every example spec, the own plant against MuJoCo, on a local Dask cluster, with a report
of the verdict and the worst case of each measure (acroboter.studies.plant_differential, docs/plant.md). With
`--cranes N`, on N generated cranes instead, each also flown closed loop (acroboter.studies.generated_cranes,
docs/plant-fuzz-cranes.md). It needs the mujoco extra, and the dask extra for more than one worker (docs/extras.md)."""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import nullcontext
from functools import partial
from pathlib import Path

from ..model.ranges import FUZZ_CASES, FUZZ_CRANE_SEED, FUZZ_CRANES, FUZZ_SEED, FUZZ_TIMESTEP, WORKERS
from ..model.spec import load_spec
from ..process.extras import require
from ..process.locations import example_names, example_spec
from ..report.plant_fuzz_report import report
from ..sim.simulation import check_mujoco_timestep
from ..studies.grid import open_client, run_cases, write_rows
from ..studies.plant_differential import COLUMNS, MUJOCO_TIMESTEP, crane_of, run_case
from .entry import EXIT_BAD_INPUT, EXIT_CANNOT_RUN, guarded, progress_disabled, ranged
from .outputs import ResultsFolder, out_path, results_folder


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="acroboter plant-fuzz",
        description="Differential fuzzing of the plant: random open-loop experiments on every example spec, the own "
                    "plant against MuJoCo, with the own plant's invariants checked at every substep (docs/plant.md). "
                    "Exit status: 0 every case agrees, 1 a case failed (listed in the report with the command that "
                    "replays it), 2 bad input, 3 cannot run, 130 interrupted.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--cases", type=ranged(FUZZ_CASES), default=None,
                   help="experiments, spread over the specs (default 2000); with --cranes, per crane (default 10)")
    p.add_argument("--cranes", type=ranged(FUZZ_CRANES), default=None,
                   help="fuzz N generated cranes instead of the example specs (acroboter.model.crane_generator): "
                        "drawn from --crane-seed on until N have a static equilibrium with every winch pulling")
    p.add_argument("--crane-seed", type=ranged(FUZZ_CRANE_SEED), default=0,
                   help="with --cranes: the first crane's seed")
    p.add_argument("--no-closed-loop", dest="closed_loop", action="store_false",
                   help="with --cranes: open-loop experiments only (no closed-loop runs of every method)")
    p.add_argument("--seed", type=ranged(FUZZ_SEED), default=0, help="seed of the first case (case i: seed + i)")
    p.add_argument("--spec", action="append", default=argparse.SUPPRESS,
                   help="an example spec's name (repeat for several; default: every one in model_spec/)")
    p.add_argument("--mujoco-timestep", type=ranged(FUZZ_TIMESTEP), default=MUJOCO_TIMESTEP,
                   help="MuJoCo's step, s (must divide the plant step)")
    p.add_argument("--workers", type=ranged(WORKERS), default=2, help="worker processes of the local Dask cluster "
                   "(1: in this process, no Dask)")
    p.add_argument("--out", type=out_path, default=Path("results/plant_fuzz"), help="output folder")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    # the extras first (MissingExtraError: one line with the `pip install`, exit 2): before any spec is read
    require("mujoco", "acroboter plant-fuzz (MuJoCo is its oracle)")
    if args.workers > 1:
        require("dask", f"acroboter plant-fuzz --workers {args.workers}", "--workers 1 runs in this process without it")
    args.spec = getattr(args, "spec", None)
    if args.cranes is not None and args.spec:
        p.error("--spec and --cranes: one or the other (the example specs, or generated cranes)")
    if args.cases is None:
        args.cases = 2000 if args.cranes is None else 10
    try:  # it must divide every spec's plant step (the examples': 2 ms), checked before any work
        for name in args.spec or example_names():
            if name in example_names():
                spec = load_spec(example_spec(name))
                check_mujoco_timestep(spec.simulation.step, args.mujoco_timestep, 1.0 / spec.controller.rate_hz)
    except ValueError as err:
        p.error(f"--mujoco-timestep: {str(err).removeprefix('mujoco_timestep: ')}")
    return args


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.cranes is not None:
        with results_folder(args.out, "plant-fuzz", expected=CRANE_FILES) as folder:
            return _fuzz_cranes(args, folder)
    with results_folder(args.out, "plant-fuzz", expected=["plant_fuzz.csv", "report.md"]) as folder:
        return _fuzz(args, folder)  # --out checked before any work


def _fuzz(args: argparse.Namespace, folder: ResultsFolder) -> int:
    from tqdm import tqdm

    names = args.spec or example_names()
    unknown = [n for n in names if n not in example_names()]
    if unknown:
        print(f"error: --spec {unknown[0]}: not an example (they are {', '.join(example_names())})", file=sys.stderr)
        return EXIT_BAD_INPUT
    for name in names:  # build here, once: the workers only load
        crane_of(name)
    cases = [(names[i % len(names)], args.seed + i) for i in range(args.cases)]
    t0 = time.perf_counter()
    # The task lives in an importable module (acroboter.studies.plant_differential): it pickles as a reference
    # however this one is started, without the cranes loaded here.
    task = partial(run_case, mujoco_timestep=args.mujoco_timestep)
    with (open_client(None, args.workers) if args.workers > 1 else nullcontext(None)) as client, \
            tqdm(total=len(cases), unit="case", desc="plant-fuzz", file=sys.stderr,
                 disable=progress_disabled(args.quiet), smoothing=0.0) as bar:
        failures = 0

        def done(case, row):
            nonlocal failures
            failures += not row["passed"]
            bar.set_postfix_str(f"{failures} failed", refresh=False)
            bar.update(1)

        rows = run_cases(task, cases, client, name="plant-fuzz", on_done=done)
    wall = time.perf_counter() - t0
    write_rows(folder.staging / "plant_fuzz.csv", rows, COLUMNS)
    text = report(rows, wall, args.workers, args.mujoco_timestep)
    (folder.staging / "report.md").write_text(text, encoding="utf-8")
    folder.publish()
    print(text)
    print(f"results in {args.out}/ (plant_fuzz.csv, report.md)")
    return 0 if all(r["passed"] for r in rows) else 1


CRANE_FILES = ["cranes.csv", "plant_fuzz.csv", "closed_loop.csv", "report.md"]


def _fuzz_cranes(args: argparse.Namespace, folder: ResultsFolder) -> int:
    """N generated cranes (drawn until N are accepted, at most MAX_DRAWS_PER_CRANE × N), a task per crane."""
    from tqdm import tqdm

    from ..report.crane_fuzz_report import crane_report
    from ..studies.generated_cranes import CLOSED_COLUMNS, CRANE_COLUMNS, run_crane

    t0 = time.perf_counter()
    # crane S's experiments: seeds args.seed .. + cases - 1, drawn for that crane (experiment_of)
    task = partial(run_crane, cases=args.cases, case_seed=args.seed, closed_loop=args.closed_loop,
                   mujoco_timestep=args.mujoco_timestep)
    cranes: list[dict] = []
    open_rows: list[dict] = []
    closed_rows: list[dict] = []
    accepted = 0
    next_seed = args.crane_seed
    with (open_client(None, args.workers) if args.workers > 1 else nullcontext(None)) as client, \
            tqdm(total=args.cranes, unit="crane", desc="plant-fuzz cranes", file=sys.stderr,
                 disable=progress_disabled(args.quiet), smoothing=0.0) as bar:
        failures = 0

        def done(case, out):
            nonlocal failures, accepted
            row = out["crane"]
            if not row["status"].startswith("rejected"):
                accepted += 1
                failures += row["status"] != "agrees"
                bar.update(1)
            bar.set_postfix_str(f"{failures} failed, {len(cranes) + 1 - accepted} rejected", refresh=False)
            cranes.append(row)

        while accepted < args.cranes and next_seed - args.crane_seed < MAX_DRAWS_PER_CRANE * args.cranes:
            # a batch of the cranes still needed (a rejected one is replaced by the next seed)
            seeds = list(range(next_seed, next_seed + args.cranes - accepted))
            next_seed += len(seeds)
            batch = run_cases(task, seeds, client, name="crane", on_done=done)
            for out in batch:
                open_rows += out["open"]
                closed_rows += out["closed"]
    wall = time.perf_counter() - t0
    cranes.sort(key=lambda r: r["seed"])
    write_rows(folder.staging / "cranes.csv", cranes, CRANE_COLUMNS)
    write_rows(folder.staging / "plant_fuzz.csv", open_rows, COLUMNS)
    write_rows(folder.staging / "closed_loop.csv", closed_rows, CLOSED_COLUMNS)
    text = crane_report(cranes, open_rows, closed_rows, wall, args.workers, args.mujoco_timestep)
    (folder.staging / "report.md").write_text(text, encoding="utf-8")
    folder.publish()
    print(text.split("\n\n")[1] if "\n\n" in text else text)
    print(f"results in {args.out}/ ({', '.join(CRANE_FILES)})")
    if accepted < args.cranes:
        print(f"error: only {accepted} of {args.cranes} cranes drawn from seed {args.crane_seed} have an equilibrium "
              f"with every winch pulling (of {next_seed - args.crane_seed} drawn)", file=sys.stderr)
        return EXIT_CANNOT_RUN
    return 0 if all(r["status"] == "agrees" for r in cranes if not r["status"].startswith("rejected")) else 1


MAX_DRAWS_PER_CRANE = 5  # cranes drawn per crane asked for, at most (about 1 in 6 is rejected)


if __name__ == "__main__":
    sys.exit(main())
