"""The local Dask cluster of a study, in a process (and a session) of its own: `local_cluster(workers)`.

A terminal's Ctrl-C reaches every process of its foreground process group. Were the cluster's worker processes
in the command's group, each would print its own KeyboardInterrupt traceback and the command would wait for
the cluster's orderly close. So the command starts the cluster as `python -m acroboter.studies.cluster WORKERS
FD` in a new session: the scheduler and its worker processes never see the terminal's Ctrl-C (and ignore
SIGINT besides), the command alone does, and it ends the cluster itself (SIGTERM to the session: at once).

The cluster process writes the scheduler's address to the pipe FD, then serves until its standard input closes
(the command is done, or died), closes the cluster in order and exits. What it and its workers print (Dask's
logs, a worker's warnings) goes to a pipe the command reads: shown with -v (debug), never on a user's terminal
otherwise, and named in the error when the cluster does not start.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator

log = logging.getLogger("acroboter")

START_TIMEOUT_S = 120.0  # the cluster's scheduler address, at the latest (a loaded machine takes seconds)
CLOSE_TIMEOUT_S = 10.0  # an orderly close, at the latest; then SIGKILL


class ClusterError(RuntimeError):
    """The local cluster did not start (its own output is in the message)."""


@contextlib.contextmanager
def local_cluster(workers: int) -> Iterator[str]:
    """The scheduler address of a LocalCluster of `workers` single-threaded worker processes on 127.0.0.1, in a
    session of its own; closed in order when the block ends, ended at once on an error or Ctrl-C."""
    read_fd, write_fd = os.pipe()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}  # the same imports as here
    proc = subprocess.Popen([sys.executable, "-m", "acroboter.studies.cluster", str(workers), str(write_fd)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            pass_fds=(write_fd,), start_new_session=True, env=env)
    os.close(write_fd)
    output: deque[str] = deque(maxlen=30)
    drain = threading.Thread(target=_drain, args=(proc, output), name="acroboter cluster output", daemon=True)
    drain.start()
    orderly = False
    try:
        address = _read_address(read_fd, proc)
        if not address:
            proc.wait(timeout=5)
            drain.join(timeout=1)
            raise ClusterError("the local Dask cluster did not start" + (": " + " | ".join(output) if output else ""))
        yield address
        orderly = True
    finally:
        os.close(read_fd)
        _stop(proc, orderly)


def _read_address(fd: int, proc: subprocess.Popen) -> str:
    """The first line written to `fd` ('' when the cluster process ended or timed out first)."""
    data, deadline = b"", time.monotonic() + START_TIMEOUT_S
    while b"\n" not in data and time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.5)  # a Ctrl-C here raises at once
        if ready:
            chunk = os.read(fd, 1024)
            if not chunk:
                break
            data += chunk
        elif proc.poll() is not None:
            break
    return data.split(b"\n")[0].decode().strip() if b"\n" in data else ""


def _drain(proc: subprocess.Popen, output: deque) -> None:
    for raw in proc.stdout:
        line = raw.decode(errors="replace").rstrip()
        if line:
            output.append(line)
            log.debug("dask: %s", line)


def _stop(proc: subprocess.Popen, orderly: bool) -> None:
    """End the cluster: in order (its stdin closed) after a study, at once (SIGTERM to its session) otherwise."""
    if orderly:
        with contextlib.suppress(OSError):
            proc.stdin.close()
        try:
            proc.wait(timeout=CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pass
    _signal_session(proc, signal.SIGTERM)
    try:
        proc.wait(timeout=2.0)
    except subprocess.TimeoutExpired:
        _signal_session(proc, signal.SIGKILL)
        proc.wait()
    with contextlib.suppress(OSError):
        proc.stdin.close()


def _signal_session(proc: subprocess.Popen, signum: int) -> None:
    """Signal the cluster's whole process group (its scheduler and workers: its session's)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signum)


def serve(workers: int, address_fd: int) -> int:
    """The cluster process: start the cluster, write its address to `address_fd`, serve until stdin closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # inherited by the workers (SIG_IGN survives their exec)
    from distributed import LocalCluster

    # Processes, one thread each: a task holds the GIL for its whole run, and a model is per thread. No
    # dashboard, and its HTTP port chosen freely (the default 8787 may be another cluster's: a warning). Logs
    # at CRITICAL only: a failed case comes back through its future, and on a loaded machine the heartbeats
    # to a scheduler that is shutting down log CommClosedError tracebacks that are noise.
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs={"dashboard_address": ":0"},
                      silence_logs=logging.CRITICAL) as cluster:
        with os.fdopen(address_fd, "w") as out:
            out.write(f"{cluster.scheduler_address}\n")
        sys.stdin.buffer.read()  # until the command closes it, or dies
    return 0


if __name__ == "__main__":
    sys.exit(serve(int(sys.argv[1]), int(sys.argv[2])))
