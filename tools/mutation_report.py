"""The kill rate per module of the `make mutation` runs in build/mutation/ (docs/mutation.md).

    python tools/mutation_report.py [--survivors] [--markdown]

Reads mutmut's verdicts (mutants/**/*.py.meta) of every selection folder under build/mutation/ and
each survivor's change (its function against mutmut's copy of the original, by difflib), and counts a
survivor as equivalent only when tools/mutation_equivalent.toml lists its change (module, function,
the original and the mutated line) with the reason it cannot change what the module computes. The
entries match by content, not by mutmut's mutant number, so they outlive edits elsewhere in the file.

Kill rate = (killed + timeout) / (mutants the tests reach − equivalent − numerically equivalent); a reached
mutant that ended otherwise (suspicious, segfault, interrupted) is column `other` and counts as not killed.
Mutants that no test of the selection reaches are reported apart (`no tests`): not killed and not excused.
A run of `tools/mutation.py --sample N` leaves the mutants it did not draw `not checked`; its kill rate is then the
sample's, given with its 95 % Wilson score interval for the rate over all the module's mutants.
"""

from __future__ import annotations

import argparse
import ast
import difflib
import json
import math
import sys
import tomllib
from collections import Counter
from pathlib import Path

from mutmut.stats import status_by_exit_code  # mutmut's own reading of a mutant's exit code

REPO = Path(__file__).resolve().parent.parent
ROOT = REPO / "build" / "mutation"
EQUIVALENT = REPO / "tools" / "mutation_equivalent.toml"


def function_sources(mutated: Path) -> dict[str, str]:
    """Every (method) definition of mutmut's mutated copy by its mangled name, e.g. xǁClassǁf__mutmut_3."""
    source = mutated.read_text()
    tree, text = ast.parse(source), source.splitlines()
    found = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and "__mutmut_" in node.name:
            # the whole definition (a mutated default argument is on the def line), under one name
            found[node.name] = "\n".join(text[node.lineno - 1:node.end_lineno]).replace(node.name, "f", 1)
    return found


def function_name(mangled: str) -> str:
    """mutmut's mangled name as the source spells it: xǁClassǁmethod -> Class.method, x_function -> function."""
    if mangled.startswith("xǁ"):
        return mangled[2:].replace("ǁ", ".")
    return mangled.removeprefix("x_")


def change(sources: dict[str, str], mutant: str) -> tuple[str, str]:
    """(original lines, mutated lines) of one mutant, stripped, each joined by ' / '."""
    base = mutant.rsplit("__mutmut_", 1)[0]
    old, new = sources[base + "__mutmut_orig"].splitlines(), sources[mutant].splitlines()
    removed, added = [], []
    for line in difflib.ndiff(old, new):
        if line.startswith("- "):
            removed.append(line[2:].strip())
        elif line.startswith("+ "):
            added.append(line[2:].strip())
    return " / ".join(removed), " / ".join(added)


# LAPACK flags whose change cannot alter a result here (scipy's f2py wrappers; every factor in the package is
# made and read in the upper triangle, potrf's lower=0 with potrs' lower=0):
LAPACK_FLAGS = {
    "lower": ("None or no argument is f2py's default, 0: the same upper triangle the call asked for", {0}),
    "compute_v": ("None or no argument is f2py's default, 1: eigenvectors are computed as asked", {1}),
    "clean": ("whether potrf zeroes the triangle it does not use; potrs reads only the factor's own triangle", None),
    "overwrite_a": ("whether LAPACK may reuse the input's memory: the input is a temporary or a buffer rewritten "
                    "before it is read again, and the result is taken from the returned array", None),
    "overwrite_b": ("whether LAPACK may reuse the right-hand side's memory: the result is taken from the returned "
                    "array", None),
}


def lapack_flag_equivalent(old: str, new: str) -> str | None:
    """The reason a mutant that only changes one LAPACK flag of a potrf/potrs/syevd/gesv call is equivalent, or None."""
    def call(line):
        try:
            tree = ast.parse(line.split("#")[0].strip())
        except SyntaxError:
            return None
        found = [n for n in ast.walk(tree) if isinstance(n, ast.Call)
                 and ast.unparse(n.func).split(".")[-1].lstrip("_").lstrip("d") in ("potrf", "potrs", "syevd", "gesv")]
        return found[0] if len(found) == 1 else None
    a, b = call(old), call(new)
    if a is None or b is None or ast.unparse(a.func) != ast.unparse(b.func) or \
            [ast.unparse(x) for x in a.args] != [ast.unparse(x) for x in b.args]:
        return None
    ka = {k.arg: ast.literal_eval(k.value) for k in a.keywords}
    kb = {k.arg: ast.literal_eval(k.value) for k in b.keywords}
    changed = [k for k in set(ka) | set(kb) if ka.get(k, "absent") != kb.get(k, "absent")]
    if len(changed) != 1 or changed[0] not in LAPACK_FLAGS:
        return None
    flag = changed[0]
    why, only_from = LAPACK_FLAGS[flag]
    if only_from is not None and not (ka.get(flag) in only_from and kb.get(flag, None) is None):
        return None  # e.g. lower=0 -> lower=1: a different triangle, not equivalent
    return f"LAPACK flag {flag}: {why}"


def wilson_interval(killed: int, judged: int, z: float = 1.959964) -> tuple[float, float]:
    """The 95 % Wilson score interval of a rate seen as `killed` of `judged` mutants drawn at random."""
    if judged == 0:
        return float("nan"), float("nan")
    p = killed / judged
    centre = (p + z * z / (2 * judged)) / (1 + z * z / judged)
    half = z * math.sqrt(p * (1 - p) / judged + z * z / (4 * judged * judged)) / (1 + z * z / judged)
    return centre - half, centre + half


def rate_text(row: dict) -> str:
    """The kill rate, with the interval when the run judged a random sample of the module's mutants."""
    text = f"{100 * row['kill_rate']:.1f} %"
    if row["counts"].get("not checked"):
        low, high = wilson_interval(row["counts"].get("killed", 0) + row["counts"].get("timeout", 0), row["judged"])
        text += f" (a sample; 95 %: {100 * low:.1f}–{100 * high:.1f} %)"
    return text


def equivalents() -> list[dict]:
    return tomllib.loads(EQUIVALENT.read_text()).get("equivalent", []) if EQUIVALENT.is_file() else []


def is_listed(entries, module, function, old, new):
    for e in entries:
        if (e["module"] == module and e["function"] == function and e["old"] == old and e["new"] == new
                and e["why"].strip() and not e["why"].startswith("TODO")):
            return e
    return None


def collect(root: Path = ROOT) -> list[dict]:
    """One row per mutated module of every selection folder under `root` (or of `root` itself)."""
    entries = equivalents()
    rows = []
    metas = sorted(root.glob("*/mutants/acroboter/**/*.py.meta")) + sorted(root.glob("mutants/acroboter/**/*.py.meta"))
    for meta in metas:
        mutated = meta.with_suffix("")
        mutants = next(p for p in meta.parents if p.name == "mutants")
        module = str(mutated.relative_to(mutants / "acroboter"))
        verdicts = json.loads(meta.read_text())["exit_code_by_key"]
        sources = function_sources(mutated)
        counts, survivors = Counter(), []
        for key, code in verdicts.items():
            status = status_by_exit_code[code]
            name = key.rsplit(".", 1)[-1]
            function = function_name(name.rsplit("__mutmut_", 1)[0])
            if status == "survived":
                old, new = change(sources, name)
                listed = is_listed(entries, module, function, old, new)
                why = listed["why"] if listed else lapack_flag_equivalent(old, new)
                if why:
                    status = "numerically equivalent" if listed and listed.get("kind") == "numerical" else "equivalent"
                survivors.append({"mutant": name, "function": function, "old": old, "new": new, "equivalent": why})
            counts[status] += 1
        # reached and not excused: a mutant that ended any other way (suspicious, segfault, interrupted) is not a kill
        judged = len(verdicts) - sum(counts[s] for s in ("equivalent", "numerically equivalent", "no tests",
                                                         "skipped", "not checked"))
        other = judged - counts["killed"] - counts["timeout"] - counts["survived"]
        if other:
            counts["other"] = other
        rate = (counts["killed"] + counts["timeout"]) / judged if judged else float("nan")
        rows.append({"selection": mutants.parent.name, "judged": judged,
                     "module": module, "counts": dict(counts), "total": len(verdicts), "kill_rate": rate,
                     "survivors": survivors})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--survivors", action="store_true", help="list each survivor's change")
    parser.add_argument("--markdown", action="store_true", help="the table as Markdown (docs/mutation.md)")
    parser.add_argument("--equivalent", action="store_true", help="list the equivalent mutants and why")
    parser.add_argument("--draft", action="store_true",
                        help="TOML entries for the survivors not listed yet, to be judged (why = \"TODO ...\")")
    parser.add_argument("--root", type=Path, default=ROOT, help="where the runs are (default build/mutation/)")
    args = parser.parse_args(argv)
    rows = collect(args.root)
    if not rows:
        print(f"no mutation run in {args.root} (make mutation)", file=sys.stderr)
        return 3
    if args.draft:
        for r in rows:
            for s in r["survivors"]:
                if not s["equivalent"]:
                    print(f'[[equivalent]]\nmodule = "{r["module"]}"\nfunction = "{s["function"]}"\n'
                          f"old = {json.dumps(s['old'], ensure_ascii=False)}\n"
                          f"new = {json.dumps(s['new'], ensure_ascii=False)}\n"
                          f'why = "TODO {s["mutant"]}"\n')
        return 0
    cols = ("killed", "timeout", "survived", "other", "equivalent", "numerically equivalent", "no tests",
            "not checked")
    if args.markdown:
        print("| module | mutants | " + " | ".join(cols) + " | kill rate |")
        print("|---|---|" + "---|" * len(cols) + "---|")
    for r in rows:
        c = r["counts"]
        if args.markdown:
            print(f"| {r['module']} | {r['total']} | " + " | ".join(str(c.get(k, 0)) for k in cols)
                  + f" | {rate_text(r)} |")
        else:
            print(f"{r['module']:28s} {r['total']:4d} mutants  " + "  ".join(f"{k} {c.get(k, 0)}" for k in cols)
                  + f"  kill rate {rate_text(r)}")
        for s in r["survivors"]:
            if (args.survivors and not s["equivalent"]) or (args.equivalent and s["equivalent"]):
                print(f"    {s['mutant']}\n        - {s['old']}\n        + {s['new']}")
                if s["equivalent"]:
                    print(f"        equivalent: {s['equivalent']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
