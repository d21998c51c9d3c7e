"""`make mutation`: mutmut 3 over the core modules, in a scratch copy of the checkout per selection (docs/mutation.md).

    python tools/mutation.py [MODULE ...] [--tests TEST_FILE ...] [--max-children N] [--only GLOB ...] [--work DIR]

MODULE is a path under acroboter/ (default: every module of CORE). The checkout's acroboter/, tests/,
generated/ and model_spec/ are copied into build/mutation/<modules>/ with a [tool.mutmut] section that mutates
only the chosen modules (every other file of the package is listed in do_not_mutate), and mutmut runs
there with the test selection TESTS (default: the physics and control-law tests, not the freshness
check and not the cross-implementation comparisons, which compare against a second implementation
of the same code rather than an oracle). Compiled libraries come from the checkout's build/cache/
(ACROBOTER_CACHE_DIR, as `make` sets it).

Generator modules (codegen/*): a mutant of the generator changes nothing until the C is regenerated.
The library loader (runtime/cache.py) regenerates into the cache when the generator's fingerprint
differs from the shipped manifest's; mutmut puts all of a file's mutants behind run-time trampolines
in one mutated copy, so that copy's fingerprint differs for every mutant alike and each test process
would regenerate and compile every spec it loads (tens of seconds per spec, per mutant): out of reach
on a shared 2-core machine. The target therefore takes runtime modules only and refuses codegen/;
a generator mutant is checked the way the planted-bug table of docs/mutation.md was: apply it
(`mutmut apply NAME` in build/mutation/ or by hand), `make generate`, run the tests, revert.
"""

from __future__ import annotations

import argparse
import os
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
GENERATOR = ["codegen/symbolic.py", "codegen/structured.py", "codegen/plant.py"]
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
    parser.add_argument("modules", nargs="*", default=CORE,
                        help="modules under acroboter/ to mutate (default: the runtime core, CORE)")
    parser.add_argument("--tests", nargs="+", default=TESTS, help="the test files that judge the mutants "
                        "(default: the physics and control-law tests, TESTS)")
    parser.add_argument("--max-children", type=int, default=2, help="parallel test processes (default 2)")
    parser.add_argument("--only", nargs="+", help="mutants whose names match these globs, e.g. "
                        "'acroboter.control.distribution.xǁBoundedInputsǁaccept*' (default: all)")
    parser.add_argument("--work", type=Path, help="the scratch folder (default build/mutation/<modules>/)")
    args = parser.parse_args(argv)
    modules = [m.removeprefix("acroboter/") for m in args.modules]
    for m in modules:
        if m in GENERATOR or m.startswith("codegen/"):
            parser.error(f"{m}: a generator module; its mutants act only after regenerating the C (see this "
                         "script's docstring and docs/mutation.md)")
        if not (REPO / "acroboter" / m).is_file():
            parser.error(f"{m}: no such module under acroboter/")
    bad = EXCLUDED.intersection(args.tests)
    if bad:
        parser.error(f"{', '.join(sorted(bad))}: not an oracle (freshness or a second implementation)")
    # one scratch folder per selection, so the survivors of each module stay to be read (`mutmut show`)
    WORK = args.work or MUTATION_ROOT / ("+".join(Path(m).stem for m in modules) if modules != CORE else "all")
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
        f"tests_dir = {toml_list(args.tests)}\n"
        'also_copy = ["generated/", "model_spec/"]\n'
    )
    (WORK / "pyproject.toml").write_text(pyproject)
    env = dict(os.environ)
    env.setdefault("ACROBOTER_CACHE_DIR", str(REPO / "build" / "cache"))
    # the console script, not `python -m mutmut`: the mutants import mutmut.__main__, which must not be __main__
    mutmut = [str(Path(sys.executable).parent / "mutmut")]
    print(f"mutating {', '.join(sorted(keep))} with {len(args.tests)} test files in {WORK}", flush=True)
    chosen = list(args.only or [])
    done = subprocess.run([*mutmut, "run", "--max-children", str(args.max_children), *chosen], cwd=WORK, env=env)
    subprocess.run([*mutmut, "results"], cwd=WORK, env=env)
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())
