"""`make mutation`: mutmut 3 over the core modules, in a scratch copy of the checkout per selection (docs/mutation.md).

    python tools/mutation.py [MODULE ...] [--tests TEST_FILE ...] [--max-children N] [--only GLOB ...] [--work DIR]
                             [--sample N [--seed S]]

MODULE is a path under acroboter/ (default: every module of CORE). The checkout's acroboter/, tests/,
generated/ and model_spec/ are copied into build/mutation/<modules>/ with a [tool.mutmut] section that mutates
only the chosen modules (every other file of the package is listed in do_not_mutate), and mutmut runs
there with the test selection TESTS (default: the physics and control-law tests, not the freshness
check and not the cross-implementation comparisons, which compare against a second implementation
of the same code rather than an oracle). Compiled libraries come from the checkout's build/cache/
(ACROBOTER_CACHE_DIR, as `make` sets it).

Generator modules (codegen/symbolic.py, solver_terms.py, plant_step.py): a mutant of the generator changes
nothing in the compiled C, and regenerating and compiling every spec per mutant (tens of seconds per spec)
is out of reach on a shared 2-core machine. Their selection runs with ACROBOTER_TEST_MODELS=casadi
(tests/conftest.py): every model the tests load is the generator's functions evaluated by CasADi's VM in
the test process (acroboter.runtime.casadi_backend.CasadiModel, no C), so a mutant acts at once, and the
tests judge it against their oracles (the SymPy derivation, the control laws in numpy, closed-form
physics). Without modules, `make mutation` runs the runtime core and then the generator, two selections.

--sample N judges N of the selection's mutants drawn uniformly at random (seeded): a module whose every mutant
costs the whole test selection (the generator on CasADi's VM, the plant's step) is then measured in minutes,
and tools/mutation_report.py gives the kill rate of the sample with its 95 % interval (Wilson).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
MUTATION_ROOT = REPO / "build" / "mutation"
CORE = [
    "control/controllers.py", "control/recovery.py", "control/distribution.py",
    "sim/plant.py", "sim/cable_events.py", "sim/sensing.py",
]
GENERATOR = ["codegen/symbolic.py", "codegen/solver_terms.py", "codegen/plant_step.py"]
# The generator's judges: each runs on the CasADi VM's models and compares with an oracle of its own.
GENERATOR_TESTS = [
    "tests/test_sympy_oracle.py", "tests/test_control_law.py", "tests/test_controller_contract.py",
    "tests/test_collocated.py", "tests/test_physics.py",
]
TESTS = [
    "tests/test_control_law.py", "tests/test_collocated.py", "tests/test_closed_loop.py",
    "tests/test_distribution.py", "tests/test_exact_distribution.py", "tests/test_limits.py",
    "tests/test_redundancy.py", "tests/test_physics.py", "tests/test_unilateral.py",
    "tests/test_plant_mismatch.py", "tests/test_sensing.py", "tests/test_integral_action.py",
]
# Never part of a selection: the freshness check and the cross-implementation comparisons.
EXCLUDED = {"tests/test_freshness.py", "tests/test_generated_integrity.py", "tests/test_integrity_chain.py",
            "tests/test_export_step.py", "tests/test_export_controller.py", "tests/test_compiled_vs_casadi.py"}


def toml_list(items) -> str:
    return "[" + ", ".join(f'"{i}"' for i in items) + "]"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("modules", nargs="*",
                        help="modules under acroboter/ to mutate (default: the runtime core, CORE, then the "
                        "generator, GENERATOR, as two selections)")
    parser.add_argument("--tests", nargs="+", help="the test files that judge the mutants (default: the "
                        "physics and control-law tests, TESTS; for generator modules GENERATOR_TESTS)")
    parser.add_argument("--max-children", type=int, default=2, help="parallel test processes (default 2)")
    parser.add_argument("--only", nargs="+", help="mutants whose names match these globs, e.g. "
                        "'acroboter.control.distribution.xǁBoundedInputsǁaccept*' (default: all)")
    parser.add_argument("--work", type=Path, help="the scratch folder (default build/mutation/<modules>/)")
    parser.add_argument("--sample", type=int, metavar="N", help="judge N mutants drawn at random from the selection's "
                        "(or from those --only matches); the report gives the sample's kill rate with its 95 %% "
                        "interval (default: every mutant)")
    parser.add_argument("--seed", type=int, default=2026, help="the seed of --sample's draw (default 2026)")
    args = parser.parse_args(argv)
    if args.sample is not None and args.sample < 1:
        parser.error(f"--sample {args.sample}: give the number of mutants to judge, 1 or more")
    if not args.modules:
        if args.work or args.only:
            parser.error("--work and --only need the modules named")
        return max(select(CORE, args.tests or TESTS, args, "all"), select(GENERATOR, args.tests or GENERATOR_TESTS,
                                                                          args, "generator"))
    modules = [m.removeprefix("acroboter/") for m in args.modules]
    for m in modules:
        if not (REPO / "acroboter" / m).is_file():
            parser.error(f"{m}: no such module under acroboter/")
    generator = any(m.startswith("codegen/") for m in modules)
    tests = args.tests or (GENERATOR_TESTS if generator else TESTS)
    bad = EXCLUDED.intersection(tests)
    if bad:
        parser.error(f"{', '.join(sorted(bad))}: not an oracle (freshness or a second implementation)")
    return select(modules, tests, args, "+".join(Path(m).stem for m in modules))


def select(modules: list[str], tests: list[str], args, name: str) -> int:
    """One mutmut run: `modules` mutated, judged by `tests`, in build/mutation/<name>/ (or --work)."""
    # one scratch folder per selection, so the survivors of each module stay to be read (`mutmut show`)
    WORK = args.work or MUTATION_ROOT / name
    if WORK.exists():
        shutil.rmtree(WORK)
    WORK.mkdir(parents=True)
    for folder in ("acroboter", "tests", "generated", "model_spec"):
        shutil.copytree(REPO / folder, WORK / folder, ignore=shutil.ignore_patterns("__pycache__"))
    keep = {f"acroboter/{m}" for m in modules}
    others = sorted(str(p.relative_to(WORK)) for p in (WORK / "acroboter").rglob("*.py")
                    if str(p.relative_to(WORK)) not in keep)
    pyproject = (REPO / "pyproject.toml").read_text()
    pyproject += (
        "\n[tool.mutmut]\n"
        'paths_to_mutate = ["acroboter/"]\n'
        f"do_not_mutate = {toml_list(others)}\n"
        f"tests_dir = {toml_list(tests)}\n"
        'also_copy = ["generated/", "model_spec/"]\n'
        # mutmut's CPU-time limit per mutant is this times its tests' measured time; its default, 15, killed
        # mutants by the limit alone when survivors were run again after tests were added (docs/mutation.md)
        "timeout_multiplier = 50.0\n"
    )
    (WORK / "pyproject.toml").write_text(pyproject)
    env = dict(os.environ)
    env.setdefault("ACROBOTER_CACHE_DIR", str(REPO / "build" / "cache"))
    if any(m.startswith("codegen/") for m in modules):
        env["ACROBOTER_TEST_MODELS"] = "casadi"  # the models from the (mutated) generator, in process
    # the console script, not `python -m mutmut`: the mutants import mutmut.__main__, which must not be __main__
    mutmut = [str(Path(sys.executable).parent / "mutmut")]
    print(f"mutating {', '.join(sorted(keep))} with {len(tests)} test files in {WORK}", flush=True)
    chosen = list(args.only or [])
    generator = any(m.startswith("codegen/") for m in modules)
    if generator or args.sample:
        # mutmut writes its mutants and its statistics, and stops: a filter that matches no mutant
        subprocess.run([*mutmut, "run", "--max-children", str(args.max_children), "acroboter.no_such_mutant"],
                       cwd=WORK, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if generator:
        widen_generator_coverage(WORK)
    if args.sample:
        chosen = draw(WORK, chosen, args.sample, args.seed)
        print(f"judging {len(chosen)} mutants drawn at random (seed {args.seed})", flush=True)
    done = subprocess.run([*mutmut, "run", "--max-children", str(args.max_children), *chosen], cwd=WORK, env=env)
    subprocess.run([*mutmut, "results"], cwd=WORK, env=env)
    return done.returncode


def draw(work: Path, only: list[str], n: int, seed: int) -> list[str]:
    """n names drawn uniformly from the mutants mutmut wrote in `work` (those matching `only`, if given)."""
    names = sorted(key for meta in (work / "mutants").glob("acroboter/**/*.py.meta")
                   for key in json.loads(meta.read_text())["exit_code_by_key"])
    if only:
        names = [k for k in names if any(fnmatch.fnmatchcase(k, g) for g in only)]
    if not names:
        raise SystemExit(f"no mutants to draw from in {work}: run `mutmut run` there to see why")
    return sorted(random.Random(seed).sample(names, min(n, len(names))))


def widen_generator_coverage(work: Path) -> None:
    """Judge every generator mutant by every test of the selection.

    mutmut runs a mutant against the tests that called its function in its statistics run, but the generator
    runs when a model is loaded, and the tests share their models through fixtures: only the first test to load
    each spec is recorded, while the tests that judge the terms are the others. So, after mutmut's statistics run
    alone, every generator function it saw called is given every test, and the mutation run that follows reads
    those statistics."""
    path = work / "mutants" / "mutmut-stats.json"
    if not path.is_file():
        raise SystemExit(f"mutmut's statistics run wrote no {path}: run `mutmut run` in {work} to see why")
    stats = json.loads(path.read_text())
    everything = sorted(stats["duration_by_test"], key=stats["duration_by_test"].get)  # fastest first
    called = stats["tests_by_mangled_function_name"]
    for name in called:
        if name.startswith("acroboter.codegen."):
            called[name] = everything
    path.write_text(json.dumps(stats, indent=2))
    print(f"every generator function judged by all {len(everything)} tests of the selection", flush=True)


if __name__ == "__main__":
    sys.exit(main())
