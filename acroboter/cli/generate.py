"""The code generator's command lines: `acroboter generate|check [SPEC ...]` and `acroboter export-step`.

generate: write the C of specs (default: every example of model_spec/) into generated/ (in a
checkout) or --out; check: regenerate into a temporary folder and compare with generated/ (what
`make check-generated` runs). export-step: one method's complete control step as embedded C.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

from ..codegen.emit_c import generate
from ..model.spec import Spec, SpecError, load_spec
from ..process.interrupts import exit_status, remembered_interrupt
from ..process.locations import checkout_root, example_spec, shipped_generated_folder, spec_folder
from ..runtime.integrity import compare_trees
from .entry import add_parameter_options, as_option_text, check_out_folder, guarded, spec_file
from .outputs import OutputFolderError, folder_lock, no_empty_folder_left, out_path, results_folder

SPEC_DIR = spec_folder()
GENERATED_DIR = shipped_generated_folder()
REPO = checkout_root() or Path.cwd()
# Outside a checkout nothing is written next to the package: generated C and embedded steps go to
# the current folder unless --out says otherwise.
DEFAULT_GENERATED = GENERATED_DIR if checkout_root() is not None else Path("generated")
DEFAULT_EMBEDDED = REPO / "build" / "embedded" if checkout_root() is not None else Path("embedded")


def _specs(paths: list[str]) -> list[Path]:
    return [Path(p) for p in paths] if paths else sorted(SPEC_DIR.glob("*.toml"))


def load_all(spec_paths: list[Path]) -> list[tuple[Path, Spec]]:
    """Every spec, validated, with distinct names (each name is a folder of generated/)."""
    specs = [(path, load_spec(path)) for path in spec_paths]
    first: dict[str, Path] = {}
    for path, spec in specs:
        if spec.name in first:
            raise SpecError(str(path), [("name", f"expected a name of its own, found '{spec.name}', the name of "
                                                 f"{first[spec.name]} too: each crane needs its own name "
                                                 "(its folder generated/<name>/)")])
        first[spec.name] = path
    return specs


def _shown(path: Path) -> str:
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


def refuse_collisions(specs: list[tuple[Path, Spec]], out_root: Path) -> None:
    """A spec from elsewhere must not overwrite the generated code of a checked-in spec of the same name."""
    if out_root.resolve() != GENERATED_DIR.resolve():
        return
    checked_in: dict[str, list[Path]] = {}
    for path in sorted(SPEC_DIR.glob("*.toml")):
        try:
            checked_in.setdefault(load_spec(path).name, []).append(path.resolve())
        except SpecError:
            continue  # a broken checked-in spec is reported when it is generated itself
    for path, spec in specs:
        owners = checked_in.get(spec.name, [])
        if len(owners) > 1:
            listed = ", ".join(_shown(p) for p in owners)
            raise SpecError(str(path), [("name", f"expected a name of its own, found '{spec.name}' in {len(owners)} "
                                                 f"specs of model_spec/ ({listed}): each crane needs its own name "
                                                 f"(its folder generated/<name>/); rename the copy")])
        owner = owners[0] if owners else None
        if owner is not None and owner != path.resolve():
            raise SpecError(str(path), [("name", f"expected a name of its own, found '{spec.name}', the name of the "
                                                 f"checked-in {_shown(owner)}: generating it would overwrite "
                                                 f"generated/{spec.name}/. Rename the crane, or generate it elsewhere "
                                                 "with --out DIR")])


def compile_check(folder: Path) -> None:
    """The generated C passes the integrity chain's checks, compiles and links into a library that embeds
    what the bindings will expect (acroboter.runtime.integrity)."""
    # the CLI composes both; codegen itself stays below the runtime
    from ..runtime.compile_library import BuildError, build, sources_hash
    from ..runtime.integrity import StaleModelError, check_library, expected_embedded, verify_sources

    spec_name = json.loads((folder / "manifest.json").read_text())["spec"]
    with tempfile.TemporaryDirectory(prefix="acroboter-compile-check-") as tmp:
        tmp_root = Path(tmp)
        (tmp_root / "generated").mkdir()
        sources = tmp_root / "generated" / spec_name
        shutil.copytree(folder, sources)
        try:
            manifest = verify_sources(sources, spec_name, None)
            lib = build(spec_name, sources, tmp_root / "build")
            check_library(ctypes.CDLL(str(lib)), spec_name, expected_embedded(manifest, sources_hash(sources)), lib,
                          sources, "a bug of the code generator or the build")
        except BuildError as err:
            raise GenerationError(f"the generated C for '{spec_name}' does not compile: {err}") from None
        except StaleModelError as err:
            raise GenerationError(f"the generated C for '{spec_name}' fails its own integrity check: {err}") from None


class GenerationError(RuntimeError):
    pass


# The code generator's staging and retired folders (acroboter.codegen.emit_c): .<spec>.new-<8 characters>,
# .<spec>.old-<pid>
STAGING = re.compile(r"\.[A-Za-z0-9_]+\.(new-[a-z0-9_]{8}|old-(\d+))")


def refuse_foreign(specs: list[tuple[Path, Spec]], out_root: Path) -> None:
    """A folder <name>/ in --out that is not generated code of that spec (no manifest.json naming it) is the
    user's: never replaced (OutputFolderError, exit 2, before any work). generated/ of a checkout is the
    project's own: each of its folders is generated code."""
    if out_root.resolve() == GENERATED_DIR.resolve():
        return
    for _, spec in specs:
        folder = out_root / spec.name
        if not (folder.exists() or folder.is_symlink()):
            continue
        try:
            ours = folder.is_dir() and not folder.is_symlink() and \
                json.loads((folder / "manifest.json").read_text()).get("spec") == spec.name
        except (OSError, ValueError, AttributeError):
            ours = False
        if not ours:
            raise OutputFolderError(f"cannot write into --out {out_root}: it holds {spec.name}, which is not the "
                                    f"generated code of spec '{spec.name}' (no manifest.json of it there): move it "
                                    "away or choose another --out")


def remove_stale_staging(out_root: Path) -> None:
    """The staging and retired folders a killed generate left in `out_root` (called under its lock: no other
    generate writes there; a retired folder only when its process is gone)."""
    import os

    for entry in out_root.iterdir():
        found = STAGING.fullmatch(entry.name)
        if found is None or not entry.is_dir() or entry.is_symlink():
            continue
        if found.group(2) is not None:
            try:
                os.kill(int(found.group(2)), 0)
                continue  # alive
            except ProcessLookupError:
                pass
            except OSError:
                continue
        shutil.rmtree(entry, ignore_errors=True)


def cmd_generate(spec_paths: list[Path], out_root: Path, check_compiles: bool = True) -> int:
    specs = load_all(spec_paths)  # all valid before anything is written
    refuse_collisions(specs, out_root)
    refuse_foreign(specs, out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    # One command at a time writes into --out (a second one: exit 3, naming it); Ctrl-C at once, inside CasADi as
    # soon as it returns, and never after a folder was half replaced (acroboter.codegen.emit_c swaps whole)
    with folder_lock(out_root), remembered_interrupt() as interrupt:
        remove_stale_staging(out_root)

        def verify(folder: Path) -> None:
            interrupt.check()
            if check_compiles:
                compile_check(folder)
                interrupt.check()

        for path, spec in specs:
            out_dir = generate(spec, out_root, verify=verify)
            print(f"generated {_shown(out_dir)} from {path.name}")
    return 0


def cmd_check(spec_paths: list[Path], committed: Path, whole_tree: bool) -> int:
    """Regenerate into a temporary folder and compare with `committed`.

    With whole_tree, every folder of `committed` must come from some spec; otherwise only the
    folders of the given specs are compared.
    """
    with tempfile.TemporaryDirectory(prefix="acroboter-check-") as tmp:
        fresh = Path(tmp)
        problems = []
        for _, spec in load_all(spec_paths):
            out_dir = generate(spec, fresh)
            if not whole_tree:
                problems += compare_trees(out_dir, committed / out_dir.name, prefix=f"{out_dir.name}/")
        if whole_tree:
            problems = compare_trees(fresh, committed)
    if problems:
        print("generated/ is stale:", *problems, sep="\n  ")
        print("fix: run `acroboter generate` (in a checkout: `make generate`, then commit generated/)")
        return 1
    print(f"generated/ is up to date ({len(spec_paths)} spec(s))")
    return 0


def _not_generated_folder(out: Path) -> str | None:
    """Why `check --out` cannot compare `out` (None: it can): it must be a folder of generated code, one
    <crane>/manifest.json at least (`check --out /usr` walked the whole tree, a missing folder was "stale")."""
    from .outputs import unfit_folder

    if (problem := unfit_folder(out)) is not None:
        return problem
    if not out.is_dir():
        return f"{'a file' if out.exists() else 'nothing'} at this path; give a folder `acroboter generate` wrote"
    try:
        if not any((entry / "manifest.json").is_file() for entry in out.iterdir() if entry.is_dir()):
            return "no generated code in it (no <crane>/manifest.json); give a folder `acroboter generate` wrote"
    except OSError as err:
        return f"cannot read it ({err.strerror or err})"
    return None


@guarded
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="acroboter", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=["generate", "check"],
                        help="generate the C, or check generated/ is fresh")
    parser.add_argument("specs", nargs="*", type=spec_file,
                        help="spec files or examples' names (default: every model_spec/*.toml)")
    parser.add_argument("--out", type=out_path, default=None,
                        help="the folder written (generate; default: generated/ in a checkout, else ./generated) "
                             "or compared (check; default: the shipped generated/)")
    parser.add_argument("--no-compile-check", action="store_true",
                        help="generate: skip compiling each spec's C before it replaces the previous files")
    args = parser.parse_intermixed_args(argv)  # `generate --out DIR SPEC`: a spec after the options too
    if args.out is None:
        args.out = DEFAULT_GENERATED if args.command == "generate" else GENERATED_DIR
    if args.command == "generate":
        check_out_folder(parser, args.out)
    try:
        if args.command == "check":
            load_all(_specs(args.specs))  # a bad spec is named first, then the folder it is compared with
            if (problem := _not_generated_folder(args.out)) is not None:
                parser.error(f"--out {args.out}: {problem}")
        if args.command == "generate":
            with no_empty_folder_left(args.out):  # a failed generate leaves no empty --out it made
                return cmd_generate(_specs(args.specs), args.out, check_compiles=not args.no_compile_check)
        return cmd_check(_specs(args.specs), args.out, whole_tree=not args.specs)
    except SpecError as err:
        print(err, file=sys.stderr)
        return 2
    except GenerationError as err:
        print(f"error: {err} (the previous generated files are unchanged)", file=sys.stderr)
        return 3
    except KeyboardInterrupt as err:  # also SIGTERM, SIGHUP (acroboter.process.interrupts)
        print("interrupted: the previous generated files are unchanged", file=sys.stderr)
        return exit_status(err)
    except OSError as err:
        print(f"error: cannot write the generated files: {err}", file=sys.stderr)
        return 3


@guarded
def export_step_main(argv: list[str] | None = None) -> int:
    """`acroboter export-step`: one method's complete control step as self-contained C and a header."""
    from ..codegen.controller_c import controller_files, controller_name
    from ..codegen.export_step import (
        MLM_SYSTEMS,
        PENALTY_SYSTEMS,
        ExportError,
        export_step,
        parse_method,
        refuse_unexportable,
        step_name,
    )
    from ..model.controller_parameters import PARAMETERS
    from ..model.settings import resolve_gains

    parser = argparse.ArgumentParser(
        prog="acroboter export-step",
        description="Export one method's complete control step as self-contained C with a header.",
    )
    parser.add_argument("--spec", type=spec_file, default=example_spec(),
                        help="model spec: a TOML file or an example's name (default: %(default)s)")
    parser.add_argument("--method", default="penalty", help="mlm, penalty or iterative-N (default: %(default)s)")
    exported = [item for item in PARAMETERS if item.option and item.exported]
    add_parameter_options(parser, exported, {"ki": "--stateful only: the stateless step refuses integral action"})
    parser.add_argument("--mlm-system", choices=MLM_SYSTEMS, default="reduced",
                        help="MLM: the (m+l) system reduced by the constant M, or the full (n+m+l) one "
                        "(default: %(default)s)")
    parser.add_argument("--penalty-system", choices=PENALTY_SYSTEMS, default="auto",
                        help="penalty methods: solve the (m+k) x (m+k) multiplier matrix D^-1 + J M^-1 J^T, or the "
                        "n x n penalty matrix A = M + J^T D J; the same iterates. auto: multipliers, unless the "
                        "spec has redundant constraints (then matrix) (default: %(default)s)")
    parser.add_argument("--stateful", action="store_true",
                        help="export the stateful controller instead (docs/controller.md): a state struct and "
                        "init/step/reset with the spec's [sensing] estimator (none: the state is measured) and "
                        "integral action (ki)")
    parser.add_argument("--out", type=out_path, default=None,
                        help=f"output folder (default: {DEFAULT_EMBEDDED}/<spec>_<method>/)")
    args = parser.parse_args(argv)
    if args.out is not None:
        check_out_folder(parser, args.out)
    if args.method == "mlm":  # MLM's multipliers are the inputs: it has no recovery (nor penalty numbers) to set
        given = [item.flag for item in exported if getattr(args, item.name) is not None
                 and item.table == "controller.penalty"]
        if given:
            parser.error(f"{', '.join(given)}: the penalty methods' setting(s); mlm has none (its multipliers are "
                         "the inputs): leave them out, or export --method penalty or iterative-N")
    overrides = {item.name: getattr(args, item.name) for item in exported}  # each in its range
    try:
        spec = load_spec(args.spec)
        try:  # before any work: e.g. a kp, kd whose sampled law would be unstable
            gains = resolve_gains(spec, **overrides)
        except ValueError as err:
            print(f"error: {as_option_text(err)}", file=sys.stderr)
            return 2
        if args.method != "mlm":
            refuse_unexportable(gains, parse_method(args.method))  # before any folder is locked or crane built
        out = args.out if args.out is not None else DEFAULT_EMBEDDED / f"{spec.name}_{args.method}"
        if args.stateful:
            name = controller_name(spec, args.method, gains.recovery)
            with results_folder(out, "export-step", expected=controller_files(name)) as folder:
                from ..api.crane import Crane  # the start state and the path's numbers come from the library

                Crane.from_toml(args.spec).export_controller(args.method, folder.staging, None, args.mlm_system,
                                                             args.penalty_system, **overrides)
                written = folder.publish()
            for path in written:
                print(f"wrote {_shown(path)}")
            return 0
        name = step_name(spec, args.method, gains.recovery)
        # the output-folder contract (docs/run.md): checked and locked now, staged, swapped in; the files of the last
        # export are the current ones (an earlier export into the folder, of other gains or another method, goes)
        with results_folder(out, "export-step", expected=[f"{name}.c", f"{name}.h"]) as folder:
            export_step(args.spec, args.method, folder.staging, args.mlm_system, args.penalty_system, **overrides)
            written = folder.publish()
    except (SpecError, ExportError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for path in written:
        print(f"wrote {_shown(path)}")
    return 0


@guarded
def build_main(argv: list[str] | None = None) -> int:
    """`acroboter build`: compile the examples' libraries into the cache (acroboter.runtime.compile_library), with the
    error boundary of every command."""
    from ..runtime.compile_library import main as build

    return build(argv)


if __name__ == "__main__":
    sys.exit(main())
