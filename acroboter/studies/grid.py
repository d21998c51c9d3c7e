"""Running a grid of closed-loop cases: on a dask.distributed cluster, or in this process.

What every study over many runs of a spec shares, whatever its cases are (the penalty-number sweep,
the redundancy study, a robustness Monte Carlo):

- `parse_values`: a grid axis from the command line ("1e3:1e12", "5,10,20");
- `prepare` and `check_duration`: the checks and the one build made before any task runs;
- `crane_for_text` / `crane_for`: the spec's Crane (acroboter.api.crane), loaded once per worker thread and
  reused by every later task on the same spec: each run goes through `Crane.simulate`, as a user's would;
- `run_cases`: one task per case, on a Client or in-process, results in case order;
- `open_client`: a Client to a running scheduler or to a LocalCluster on 127.0.0.1;
- `write_rows` / `read_rows`: a grid's flat rows as CSV.

dask is an optional extra (`pip install 'acroboter[dask]'`, acroboter.process.extras): it is imported only
where a cluster is used, so importing this module, and every command's --help, works without it.
"""

from __future__ import annotations

import csv
import hashlib
import math
import re
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from ..model.ranges import Range
from ..model.spec import MAX_CONTROL_STEPS

# At most this many values per grid axis and runs per grid (checked while parsing, before any work).
MAX_GRID_VALUES = 1000
MAX_RUNS = 20_000
# Set-ups kept per worker thread: a Monte Carlo over perturbed specs must not keep every model alive.
MAX_SETUPS = 8  # cranes


class GridError(RuntimeError):
    """The grid cannot run at all (bad spec, stale or missing model library, no cluster): bad input."""


class MissingLibraryError(GridError):
    """A worker found no compiled model library: it must not build one."""


# ---------------------------------------------------------------------------------------------------
# Before any task


def parse_values(text: str, what: str = "values", range_: Range | None = None) -> list[float]:
    """Comma-separated numbers, each a value or a log range START:STOP[:PER_DECADE] (default 1 per decade), each
    value (and each range's ends, before it is expanded) in `range_` (default: positive and finite). A ValueError
    starts with `what` (none for an empty `what`: argparse names the option)."""
    head = f"{what}: " if what else ""
    values: list[float] = []

    def checked(value: float) -> float:
        problem = (range_.problem(value) if range_ is not None
                   else None if math.isfinite(value) and value > 0 else f"expected a positive finite number, found "
                                                                        f"{value:g}")
        if problem is not None:
            raise ValueError(f"{head}{problem}")
        return value

    for item in (s.strip() for s in text.split(",")):
        if not item:  # `1,,2` or a trailing comma: a value left out, or a typo
            raise ValueError(f"{head}expected comma-separated numbers or START:STOP[:PER_DECADE] ranges, found an "
                             f"empty item in '{text}'")
        parts = item.split(":")
        try:
            nums = [float(p) for p in parts]
        except ValueError:
            each = f", each {range_.text()}" if range_ is not None else ""
            raise ValueError(f"{head}expected numbers or START:STOP[:PER_DECADE] ranges{each}, "
                             f"found '{item}'") from None
        if len(nums) == 1:
            values.append(checked(nums[0]))
            continue
        if len(nums) > 3:
            raise ValueError(f"{head}a range is START:STOP[:PER_DECADE], found '{item}'")
        checked(nums[0]), checked(nums[1])
        if nums[1] < nums[0]:
            raise ValueError(f"{head}a range is START:STOP[:PER_DECADE] with 0 < START <= STOP, found '{item}'")
        per_decade = nums[2] if len(nums) == 3 else 1.0
        if not (math.isfinite(per_decade) and per_decade >= 1 and per_decade == int(per_decade)):
            raise ValueError(f"{head}points per decade must be a whole number >= 1, found '{item}'")
        lo, hi = math.log10(nums[0]), math.log10(nums[1])
        count = int(round((hi - lo) * per_decade)) + 1
        if count + len(values) > MAX_GRID_VALUES:  # refused before the list is built: "1:1e300:1e6" is cheap to type
            raise ValueError(f"{head}at most {MAX_GRID_VALUES} values, found a range of {count} in '{item}'")
        # 12 digits: from 3e3, 10 ** (lo + i) gives 3000000.000000001; the grid's values must be the
        # numbers a user would type (and finds in the CSV).
        values += [float(f"{10 ** (lo + i / per_decade):.12g}") for i in range(count)]
    if not values:
        raise ValueError(f"{head}no values given")
    return list(dict.fromkeys(values))


def require_dask(what: str, hint: str | None = None) -> None:
    """Raise MissingExtraError (an ImportError: the missing package and `pip install 'acroboter[dask]'`)
    unless dask and distributed are installed. Called before any work, so a missing extra costs no build and
    no half-written folder; the command lines call it while checking their options (exit 2)."""
    from ..process.extras import require

    require("dask", what, hint)


def prepare(spec_path: Path, duration: float | None = None):
    """Load and validate the spec (and the duration against its rate: check_duration) and then build
    its library here, once (tasks only load it); returns the spec. Nothing is built for a bad input."""
    from ..model.spec import SpecError, load_spec
    from ..runtime.cache import load_model
    from ..runtime.compiled import StaleModelError

    try:
        spec = load_spec(spec_path)
        check_duration(spec, duration)
        load_model(spec)
    except (SpecError, StaleModelError) as err:
        raise GridError(str(err)) from None
    return spec


def check_duration(spec, duration: float | None) -> None:
    """A duration of 1..MAX_CONTROL_STEPS control steps of the spec's controller (None: the whole path)."""
    from ..model.ranges import DURATION

    rate = spec.controller.rate_hz
    if duration is not None and (problem := DURATION.problem(duration)) is not None:
        raise GridError(f"--duration: {problem}")
    if duration is not None and not 1 <= round(duration * rate) <= MAX_CONTROL_STEPS:
        raise GridError(f"--duration {duration:g} s is {round(duration * rate)} control steps at {rate:g} Hz: give "
                        f"between one ({1 / rate:g} s) and {MAX_CONTROL_STEPS}")


# ---------------------------------------------------------------------------------------------------
# The pieces of a run: loaded once per worker thread (or here, for an in-process study)


_LOCAL = threading.local()  # one Crane per worker thread and spec: a Crane's runs each work on their own data


def crane_for_text(spec_text: str, source: str, build: bool = False):
    """The Crane (acroboter.api.crane) of the spec given as TOML text (what a task receives), cached per thread:
    every run of a study goes through the library, as a user's would.

    build=False (a task on a worker): never generate or compile; a missing library is a
    MissingLibraryError that tells the user to build it on the worker machines."""
    # Keyed by the text, not the parsed spec: a cache hit costs a hash, not a validation.
    return _cached("text:" + hashlib.sha256(spec_text.encode()).hexdigest(), lambda: _parse(spec_text, source), build)


def crane_for(spec, build: bool = True):
    """The Crane of a validated spec (in-process studies), cached per thread like crane_for_text."""
    return _cached("spec:" + hashlib.sha256(spec.model_dump_json().encode()).hexdigest(), lambda: spec, build)


def _parse(spec_text: str, source: str):
    import tomllib

    from ..model.spec import parse_spec

    return parse_spec(tomllib.loads(spec_text), source)


def _cached(key: str, get_spec: Callable[[], object], build: bool):
    from ..process.locations import cache_dir

    key += f"\n{cache_dir()}"  # the same spec in another cache is another library
    cache = getattr(_LOCAL, "cranes", None)
    if cache is None:
        cache = _LOCAL.cranes = OrderedDict()
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    spec = get_spec()
    cache[key] = _load(spec, build)
    while len(cache) > MAX_SETUPS:
        cache.popitem(last=False)
    return cache[key]


def _load(spec, build: bool):
    from ..api.crane import Crane
    from ..runtime.cache import load_model
    from ..runtime.compiled import NotBuiltError

    try:
        model = load_model(spec, build=build)
    except NotBuiltError as err:
        import socket

        raise MissingLibraryError(
            f"worker on {socket.gethostname()}: {err}; tasks on a worker never compile. Build it on every worker "
            f"machine (`acroboter build {spec.name}`, or run the spec once there), then rerun."
        ) from None
    return Crane(spec, model)


def worker_name() -> str:
    """The address of the dask worker running this task, or 'local' outside one."""
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):  # not installed, or not on a worker
        return "local"


def status_of(err: Exception) -> str:
    """One line saying how a run failed: 'diverged at t = T s (why)' or 'error: message'."""
    from ..sim.plant import SimulationError

    text = " ".join(str(err).split())
    if isinstance(err, SimulationError):
        found = re.search(r"at t = ([-+0-9.eE]+) s:? ?(.*)", text)
        if found:
            why = found.group(2).strip(" ()")
            return f"diverged at t = {found.group(1)} s" + (f" ({why})" if why else "")
    return f"error: {text}"


# ---------------------------------------------------------------------------------------------------
# Running the cases


@contextmanager
def open_client(scheduler: str | None = None, workers: int = 2, connect_timeout: float = 10.0) -> Iterator:
    """A dask.distributed Client: to the scheduler at `scheduler`, or to a LocalCluster of `workers`
    single-threaded worker processes on 127.0.0.1 in a session of its own (acroboter.studies.cluster: a Ctrl-C
    reaches this process alone, which ends the cluster at once; closed in order after the study)."""
    from distributed import Client

    if scheduler:
        try:
            client = Client(scheduler, timeout=connect_timeout)
        except (OSError, TimeoutError, ValueError) as err:
            raise GridError(
                f"cannot connect to the Dask scheduler at '{scheduler}' within {connect_timeout:g} s "
                f"({type(err).__name__}: {' '.join(str(err).split())}): is a scheduler running there "
                "(`dask scheduler`)? Or leave out --scheduler to use a local cluster."
            ) from None
        with client:
            yield client
        return
    if workers < 1:
        raise GridError("the local cluster needs at least one worker")
    from .cluster import ClusterError, local_cluster

    try:
        with local_cluster(workers) as address, Client(address, timeout=max(connect_timeout, 60.0)) as client:
            yield client
    except ClusterError as err:
        raise GridError(str(err)) from None


def worker_count(client) -> int:
    try:
        info = client.scheduler_info(n_workers=-1)  # newer distributed lists only a few workers by default
    except TypeError:
        info = client.scheduler_info()
    return len(info["workers"])


def run_cases(task: Callable, cases: Sequence, client=None, *, name: str = "case",
              on_done: Callable | None = None, on_error: Callable | None = None) -> list:
    """task(case) for every case, the results in case order.

    `task` must be a module-level function (or a functools.partial of one): with a `client` each case
    is one dask task, pickled as a reference that the workers import. Without a client the cases run
    here, one after the other. on_done(case, result) after each case, in completion order (a
    progress bar). A task that raises: on_error(case, err) gives its result (or raises); without
    on_error the exception propagates.
    """
    results: list = [None] * len(cases)

    def finish(i: int, get) -> None:
        try:
            results[i] = get()
        except Exception as err:  # noqa: BLE001 - on_error decides: a row saying what went wrong, or abort
            if on_error is None:
                raise
            results[i] = on_error(cases[i], err)
        if on_done is not None:
            on_done(cases[i], results[i])

    if client is None:
        for i, case in enumerate(cases):
            finish(i, lambda case=case: task(case))
        return results
    import time

    from distributed import as_completed

    # pure=False: the same case twice is two runs; the key is readable on a dashboard and unique across
    # grids submitted to one scheduler.
    futures = {client.submit(task, case, pure=False, key=f"{name}-{i}-{time.time_ns()}"): i
               for i, case in enumerate(cases)}
    try:
        for fut in as_completed(futures):
            finish(futures[fut], fut.result)
    finally:
        client.cancel(list(futures))  # on an error or Ctrl-C: the cluster stops the rest
    return results


# ---------------------------------------------------------------------------------------------------
# Rows as CSV


def write_rows(path: Path, rows: list[dict], columns: list[str]) -> None:
    """The rows as CSV with `columns` in order (None: an empty cell; other keys left out)."""
    with Path(path).open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if row.get(k) is None else row[k]) for k in columns})


def read_rows(path: Path, ints: set[str], strs: set[str]) -> list[dict]:
    """Rows of a CSV written by write_rows, typed: `ints` int, `strs` str, the rest float; empty: None."""
    rows = []
    with Path(path).open(newline="") as f:
        for raw in csv.DictReader(f):
            rows.append({k: (None if v == "" else v if k in strs else int(v) if k in ints else float(v))
                         for k, v in raw.items()})
    return rows
