"""The stack a generated C entry point needs: its deepest call chain, from the compiler's own account
(gcc -fcallgraph-info=su: each function's frame and whom it calls). For the stateful controller's header, measured
when it is exported with the compiler at hand (its version named there); None without a compiler that can say."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["measure_stack"]

_NODE = re.compile(r'node: \{ title: "([^"]+)" label: "[^\\"]*\\n[^\\"]*(?:\\n(\d+) bytes \(([\w,]+)\))?')
_EDGE = re.compile(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"')
FLAGS = ("-O2", "-fPIC")


def measure_stack(folder: Path, sources: list[str], entries: list[str]) -> tuple[dict[str, int], str] | None:
    """({entry: bytes of its deepest call chain}, the compiler's name and version) for `sources` in `folder`; None
    where no compiler (or one without -fcallgraph-info) is at hand, or a frame is dynamic (unbounded)."""
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        return None
    frames: dict[str, int] = {}
    calls: dict[str, set[str]] = {}
    with tempfile.TemporaryDirectory(prefix="acroboter-stack-") as tmp:
        for source in sources:
            done = subprocess.run([compiler, *FLAGS, "-fcallgraph-info=su", "-I", str(folder), "-c",
                                   str(Path(folder) / source), "-o", f"{Path(source).stem}.o"], cwd=tmp,
                                  capture_output=True, text=True)
            info = Path(tmp) / f"{Path(source).stem}.ci"
            if done.returncode != 0 or not info.is_file():
                return None
            text = info.read_text()
            for title, size, kind in _NODE.findall(text):
                if size:
                    if kind not in ("static", "dynamic,bounded"):  # an unbounded frame: no figure
                        return None
                    frames[_plain(title)] = int(size)
            for source_title, target in _EDGE.findall(text):
                calls.setdefault(_plain(source_title), set()).add(_plain(target))
        version = subprocess.run([compiler, "--version"], capture_output=True, text=True).stdout.splitlines()[0]
    memo: dict[str, int] = {}

    def deepest(name: str, seen: frozenset) -> int:
        if name in memo:
            return memo[name]
        if name in seen:  # recursion: no bound (none in the generated code)
            raise RecursionError(name)
        below = [deepest(callee, seen | {name}) for callee in calls.get(name, ())]
        memo[name] = frames.get(name, 0) + max(below, default=0)
        return memo[name]

    try:
        return {entry: deepest(entry, frozenset()) for entry in entries}, f"{version.strip()} {' '.join(FLAGS)}"
    except RecursionError:
        return None


def _plain(title: str) -> str:
    """'file.c:function' (a static function's node) -> 'function'."""
    return title.rpartition(":")[2]
