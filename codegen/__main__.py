"""`python -m codegen generate|check [SPEC ...]`: regenerate generated/, or check it is fresh."""

from __future__ import annotations

import argparse
import filecmp
import sys
import tempfile
from pathlib import Path

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


def cmd_generate(spec_paths: list[Path], out_root: Path) -> int:
    specs = load_all(spec_paths)  # all valid before anything is written
    for path, spec in specs:
        out_dir = generate(spec, out_root)
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m codegen", description=__doc__)
    parser.add_argument("command", choices=["generate", "check"])
    parser.add_argument("specs", nargs="*", help="spec files (default: every model_spec/*.toml)")
    parser.add_argument("--out", type=Path, default=GENERATED_DIR, help="generated/ folder (default: %(default)s)")
    args = parser.parse_args(argv)
    try:
        if args.command == "generate":
            return cmd_generate(_specs(args.specs), args.out)
        return cmd_check(_specs(args.specs), args.out, whole_tree=not args.specs)
    except SpecError as err:
        print(err, file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
