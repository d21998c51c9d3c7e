"""`python -m codegen generate|check [SPEC ...]`: regenerate generated/, or check it is fresh."""

from __future__ import annotations

import argparse
import ctypes
import filecmp
import json
import shutil
import sys
import tempfile
from pathlib import Path

from acroboter.entry import check_out_folder, guarded
from acroboter.spec import Spec, SpecError, load_spec
from codegen.generate import REPO, generate

SPEC_DIR = REPO / "model_spec"
GENERATED_DIR = REPO / "generated"


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
    """The generated C compiles and links into a library whose hashes are the manifest's."""
    from acroboter.build import BuildError, build  # the CLI composes both; codegen itself stays below the runtime

    manifest = json.loads((folder / "manifest.json").read_text())
    with tempfile.TemporaryDirectory(prefix="acroboter-compile-check-") as tmp:
        tmp_root = Path(tmp)
        (tmp_root / "generated").mkdir()
        sources = tmp_root / "generated" / manifest["spec"]
        shutil.copytree(folder, sources)
        try:
            lib = build(manifest["spec"], tmp_root / "generated", tmp_root / "build")
        except BuildError as err:
            raise GenerationError(f"the generated C for '{manifest['spec']}' does not compile: {err}") from None
        library = ctypes.CDLL(str(lib))
        for what in ("spec_model_hash", "codegen_hash"):
            fn = getattr(library, f"{manifest['spec']}_{what}")
            fn.restype = ctypes.c_char_p
            if fn().decode() != manifest[what]:
                raise GenerationError(f"the compiled library's {what} is not the manifest's")


class GenerationError(RuntimeError):
    pass


def cmd_generate(spec_paths: list[Path], out_root: Path, check_compiles: bool = True) -> int:
    specs = load_all(spec_paths)  # all valid before anything is written
    refuse_collisions(specs, out_root)
    for path, spec in specs:
        out_dir = generate(spec, out_root, verify=compile_check if check_compiles else None)
        print(f"generated {out_dir.relative_to(REPO) if out_dir.is_relative_to(REPO) else out_dir} from {path.name}")
    return 0


def compare_trees(fresh: Path, committed: Path, prefix: str = "") -> list[str]:
    """Differences between two generated trees: missing, extra and changed files."""
    problems = []
    fresh_files = {p.relative_to(fresh) for p in fresh.rglob("*") if p.is_file()}
    committed_files = {p.relative_to(committed) for p in committed.rglob("*") if p.is_file()}
    for rel in sorted(fresh_files - committed_files):
        problems.append(f"missing from generated/: {prefix}{rel}")
    for rel in sorted(committed_files - fresh_files):
        problems.append(f"in generated/ but not produced by any spec: {prefix}{rel}")
    for rel in sorted(fresh_files & committed_files):
        if not filecmp.cmp(fresh / rel, committed / rel, shallow=False):
            problems.append(f"differs from what its spec produces: {prefix}{rel}")
    return problems


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
        print("fix: run `make generate` and commit generated/")
        return 1
    print(f"generated/ is up to date ({len(spec_paths)} spec(s))")
    return 0


@guarded
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m codegen", description=__doc__)
    parser.add_argument("command", choices=["generate", "check"])
    parser.add_argument("specs", nargs="*", help="spec files (default: every model_spec/*.toml)")
    parser.add_argument("--out", type=Path, default=GENERATED_DIR, help="generated/ folder (default: %(default)s)")
    parser.add_argument("--no-compile-check", action="store_true",
                        help="generate: skip compiling each spec's C before it replaces the previous files")
    args = parser.parse_args(argv)
    if args.command == "generate":
        check_out_folder(parser, args.out)
    try:
        if args.command == "generate":
            return cmd_generate(_specs(args.specs), args.out, check_compiles=not args.no_compile_check)
        return cmd_check(_specs(args.specs), args.out, whole_tree=not args.specs)
    except SpecError as err:
        print(err, file=sys.stderr)
        return 2
    except GenerationError as err:
        print(f"error: {err} (the previous generated files are unchanged)", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("interrupted: the previous generated files are unchanged", file=sys.stderr)
        return 130
    except OSError as err:
        print(f"error: cannot write the generated files: {err}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
