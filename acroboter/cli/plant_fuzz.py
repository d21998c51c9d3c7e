"""`acroboter plant-fuzz` (`make plant-fuzz`, `python -m acroboter.plant_fuzz`): many generated open-loop
experiments on every example spec, the own plant against MuJoCo, on a local Dask cluster, with a report
of the verdict and the worst case of each measure (acroboter.studies.plant_differential, docs/plant.md). It needs the
mujoco extra, and the dask extra for more than one worker (docs/extras.md)."""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import nullcontext
from functools import partial
from pathlib import Path

from ..model.ranges import FUZZ_CASES, FUZZ_SEED, FUZZ_TIMESTEP, WORKERS
from ..model.spec import load_spec
from ..process.extras import require
from ..process.locations import example_names, example_spec
from ..report.plant_fuzz_report import report
from ..sim.simulation import check_mujoco_timestep
from ..studies.grid import open_client, run_cases, write_rows
from ..studies.plant_differential import COLUMNS, MUJOCO_TIMESTEP, crane_of, run_case
from .entry import EXIT_BAD_INPUT, guarded, progress_disabled, ranged
from .outputs import ResultsFolder, out_path, results_folder


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="acroboter plant-fuzz",
        description="Differential fuzzing of the plant: random open-loop experiments on every example spec, the own "
                    "plant against MuJoCo, with the own plant's invariants checked at every substep (docs/plant.md). "
                    "Exit status: 0 every case agrees, 1 a case failed (listed in the report with the command that "
                    "replays it), 2 bad input, 3 cannot run, 130 interrupted.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--cases", type=ranged(FUZZ_CASES), default=2000, help="experiments, spread over the specs")
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


if __name__ == "__main__":
    sys.exit(main())
