"""The one output-folder contract of every command that writes a results folder (docs/run.md).

    with results_folder(args.out, "sweep", expected=["sweep.csv"]) as folder:   # --out checked: exit 2 if unusable
        ...                                  # the work; write into folder.staging
        folder.publish()                     # swapped in; without this call (a return, an error, Ctrl-C) nothing is

- `--out` is checked before any work: an empty name, an existing file, a folder that cannot be created or
  written into is an OutputFolderError naming the option (exit 2); the check creates the folder and a
  staging dot-folder inside it, so it proves what it says.
- The results are written into the staging folder and swapped in by `publish`: the files this command's
  earlier run wrote there (listed in the folder's manifest, MANIFEST) are removed, the new ones moved in
  (summary.json last), and the manifest's entry for this command rewritten, with Ctrl-C held back.
  Nothing is removed by its name: a file the manifest does not list is the user's (or an earlier
  version's) and stays. A new result whose name is taken by such a file is refused (exit 2, naming it)
  rather than written over it: before any work for the names a command knows then (`expected`,
  `claim`), at the latest before anything is replaced.
- Without `publish` (an error, a return code, Ctrl-C) the staging folder goes, the folder is as it was,
  and a folder this call created is removed again when it is empty.
- A staging folder whose process is gone (a run killed with SIGKILL) is removed at the next start.
- One command at a time: the folder is locked (flock on the folder itself) from the check to the swap; a
  second command writing into it meanwhile is refused at once (OutputFolderBusy, exit 3, naming the other
  process), so two runs never interleave their files or the manifest.
- `accumulate=True` (mjcf, animate, study: one file per spec, video or study): a run replaces only the files of
  its own names; those of other names its earlier runs wrote stay in its entry. Every other command's last run's
  files are its current ones (export-step too: an earlier export of other gains or another method goes).
- A run that failed (exit 3) never replaces the last good results: `publish_failed(why)` swaps what it has to
  say (its records up to the failure, its summary) into `failed/<command>/` with `failure.txt` saying why,
  under a manifest entry of its own (`<command> (failed)`); the next failed run replaces that, the next good
  run removes it. Every result of the good run stays byte for byte (docs/errors.md).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from ..process.interrupts import deferred_interrupt

MANIFEST = ".acroboter-outputs.json"
FAILED = "failed"  # failed/<command>/: what a failed run (exit 3) had to say, apart from the good results
STAGING_PREFIX = ".acroboter-staging-"
FORMAT = 1


class OutputFolderError(Exception):
    """An output folder that cannot be used (bad input, exit 2): the message names the option."""


class OutputFolderBusy(Exception):
    """Another command is writing into the output folder (cannot run now, exit 3): the message names it."""


def failed_entry(command: str) -> str:
    """The manifest entry of a command's last failed run."""
    return f"{command} (failed)"


def lock_holder(fd: int) -> str:
    """Who holds the flock on the open folder `fd`: 'process PID (its command line)' from /proc/locks, or
    'another process' where that cannot be read (not Linux)."""
    st = os.fstat(fd)
    where = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    with contextlib.suppress(OSError):
        for line in Path("/proc/locks").read_text().splitlines():
            fields = line.split()
            if len(fields) > 5 and fields[1] == "FLOCK" and fields[5] == where:
                pid = fields[4]
                try:
                    argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
                    command = " ".join(Path(a.decode()).name if i == 0 else a.decode()
                                       for i, a in enumerate(argv) if a)
                except OSError:
                    return f"process {pid}"
                return f"process {pid} ({command[:120]}{'...' if len(command) > 120 else ''})"
    return "another process"


@contextlib.contextmanager
def folder_lock(folder: Path, option: str = "--out") -> Iterator[None]:
    """Hold the output folder `folder` (an existing folder) for one command: an exclusive flock on the folder
    itself, released when the block ends or the process dies. Held by another command: OutputFolderBusy.
    Where folders cannot be locked (a file system without flock) the block runs unlocked."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        yield  # checked by the caller: a folder it cannot open it will not write either
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OutputFolderBusy(f"{option} {folder}: another acroboter command is writing into it "
                                   f"({lock_holder(fd)}); wait for it to finish, or choose another {option}") from None
        except OSError:
            pass  # no flock here: unlocked
        yield
    finally:
        os.close(fd)  # releases the lock


def read_manifest(out: Path) -> dict[str, dict[str, list[str]]]:
    """The manifest's entries, command -> {"files": [...], "folders": [...]} (paths relative to `out`);
    {} without one. An unreadable or foreign manifest counts as none: then nothing is removed."""
    try:
        doc = json.loads((out / MANIFEST).read_text(encoding="utf-8"))
        commands = doc["commands"]
        return {str(c): {"files": [str(f) for f in e.get("files", [])],
                         "folders": [str(f) for f in e.get("folders", [])]} for c, e in commands.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError):  # RecursionError: JSON nested
        return {}                                                                          # thousands deep


def write_manifest(out: Path, commands: dict[str, dict[str, list[str]]]) -> None:
    """Replace the manifest in one rename (no manifest when no command has an entry)."""
    path = out / MANIFEST
    commands = {c: e for c, e in commands.items() if e["files"] or e["folders"]}
    if not commands:
        path.unlink(missing_ok=True)
        return
    doc = {"format": FORMAT, "about": "the files acroboter commands wrote into this folder; a command's next "
                                      "run replaces its own, nothing else (docs/run.md)", "commands": commands}
    tmp = out / f"{MANIFEST}.tmp"
    tmp.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _inside(out: Path, relative: str) -> Path | None:
    """`out / relative` for a manifest path that stays inside `out` (None for one that does not): no absolute
    path, no `..`, and no folder on the way that is a symbolic link (`sub -> ../victim` with "sub/mlm.csv" in a
    copied manifest removed a file outside the folder)."""
    parts = Path(relative).parts
    if not parts or Path(relative).is_absolute() or ".." in parts:
        return None
    where = out
    for part in parts[:-1]:
        where = where / part
        if where.is_symlink():
            return None
    return out.joinpath(*parts)


def _remove_files(out: Path, names: Iterable[str]) -> None:
    """Remove the files (or links) of these manifest paths; a path that leaves `out` is skipped."""
    for name in names:
        target = _inside(out, name)
        if target is not None and (target.is_file() or target.is_symlink()):
            target.unlink()


def _remove_empty_folders(out: Path, names: Iterable[str]) -> None:
    """Remove these manifest folders, deepest first, each only when empty: a file the user put there keeps it."""
    for name in sorted(names, key=lambda n: -len(Path(n).parts)):
        target = _inside(out, name)
        if target is not None and target.is_dir() and not target.is_symlink():
            with contextlib.suppress(OSError):
                target.rmdir()


def _remove_entry(out: Path, entry: dict | None) -> None:
    """Remove the files a manifest entry lists, then its folders where they are left empty."""
    if entry is not None:
        _remove_files(out, entry["files"])
        _remove_empty_folders(out, entry["folders"])


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: alive
        return True
    return True


def clean_stale_staging(out: Path) -> None:
    """Remove the staging folders of runs whose process is gone (killed before they could clean up)."""
    with contextlib.suppress(OSError):
        for entry in out.iterdir():
            name = entry.name
            if not name.startswith(STAGING_PREFIX) or not entry.is_dir() or entry.is_symlink():
                continue
            pid = name[len(STAGING_PREFIX):].split("-")[-2:-1]  # .acroboter-staging-<command>-<pid>-<random>
            if pid and pid[0].isdigit() and int(pid[0]) != os.getpid() and not _alive(int(pid[0])):
                shutil.rmtree(entry, ignore_errors=True)


class ResultsFolder:
    """An output folder opened for one command's run (use `results_folder`)."""

    def __init__(self, out: Path | str, command: str, option: str = "--out", replaces: Iterable[str] = (),
                 accumulate: bool = False):
        if str(out) == "":
            raise OutputFolderError(f"{option}: an empty folder name; give a folder, e.g. {option} results")
        self.out = Path(out)
        self.command = command
        self.option = option
        self.replaces = (command, *replaces)  # entries whose files this run's results replace
        self.accumulate = accumulate  # replace only the files of the new results' names
        self.created: list[Path] = []  # folders this call made, outermost first
        self.staging: Path = Path()
        self.published = False
        self._lock: contextlib.ExitStack | None = None

    def _error(self, problem: str) -> OutputFolderError:
        return OutputFolderError(f"cannot write results into {self.option} {self.out}: {problem}")

    def open(self, expected: Iterable[str] = ()) -> None:
        out = self.out
        try:
            if (problem := unfit_folder(out)) is not None:
                raise self._error(problem)
            if out.exists() and not out.is_dir():
                raise self._error("it is a file, not a folder")
            self.created = missing_folders(out)
            out.mkdir(parents=True, exist_ok=True)
            self._lock = contextlib.ExitStack()
            self._lock.enter_context(folder_lock(out, self.option))  # one command at a time
            clean_stale_staging(out)
            self.staging = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{self.command}-{os.getpid()}-", dir=out))
        except OSError as err:
            self._unlock()
            self._remove_created()
            raise self._error(err.strerror or str(err)) from None
        except (OutputFolderError, OutputFolderBusy):
            self._unlock()
            self._remove_created()
            raise
        try:
            self.claim(expected)
        except OutputFolderError:
            self.discard()
            raise

    def ours(self, replaces: Iterable[str] | None = None) -> set[str]:
        """The files (relative paths) the manifest lists for the entries this run replaces."""
        manifest = read_manifest(self.out)
        entries = self.replaces if replaces is None else replaces
        return {f for c in entries for f in manifest.get(c, {}).get("files", [])}

    def claim(self, names: Iterable[str], replaces: Iterable[str] | None = None) -> None:
        """Refuse (OutputFolderError) when a result to be written under one of `names` (relative paths) would
        replace a file, or sit where a file or folder is, that no earlier run of this command (or of the
        `replaces` entries) wrote."""
        ours = self.ours(replaces)
        for name in names:
            target = _inside(self.out, name)
            if target is None:
                raise ValueError(f"not a path inside the output folder: {name}")
            if name in ours:
                continue
            if target.is_symlink() or target.exists():
                raise self._error(f"it holds {name}, which no earlier `acroboter {self.command}` wrote there "
                                  f"(it is not in {MANIFEST}); move it away or choose another {self.option}")
            for parent in list(Path(name).parents)[:-1]:  # a path like study's redundant/table.md
                where = self.out / parent
                if where.exists() and not where.is_dir():
                    raise self._error(f"{parent} is a file where this run writes a folder; move it away")

    def publish(self) -> list[Path]:
        """Swap the staged results in; returns their paths in the output folder."""
        return self._swap_in(self.command, self.replaces, self.accumulate)

    def publish_failed(self, why: str) -> list[Path]:
        """Swap the staged records of a failed run into `failed/<command>/` (with `failure.txt`: `why`), leaving the
        command's good results as they were; returns their paths."""
        inner = self.staging / FAILED / self.command
        entries = list(self.staging.iterdir())
        inner.mkdir(parents=True)
        for entry in entries:
            os.replace(entry, inner / entry.name)
        (inner / "failure.txt").write_text(f"acroboter {self.command} failed (exit 3); its results in "
                                           f"{self.out} are those of its last good run.\n{why}\n", encoding="utf-8")
        record = failed_entry(self.command)
        return self._swap_in(record, (record,), accumulate=False)

    def _swap_in(self, entry: str, replaces: tuple[str, ...], accumulate: bool) -> list[Path]:
        """Move the staged files in under the manifest entry `entry`, removing the files of the `replaces` entries
        (all of them, or with `accumulate` only those of the new names)."""
        out, staging = self.out, self.staging
        new = sorted((str(p.relative_to(staging)) for p in staging.rglob("*") if not p.is_dir()),
                     key=lambda n: (Path(n).name == "summary.json", n))  # the summary last
        self.claim(new, replaces)  # a user's file under a new result's name stays; the results are refused instead
        manifest = read_manifest(out)
        old_files = [f for c in replaces for f in manifest.get(c, {}).get("files", [])]
        old_folders = {f for c in replaces for f in manifest.get(c, {}).get("folders", [])}
        kept_files, kept_folders = [], set()
        if accumulate:  # the earlier results of other names stay (and stay this command's)
            kept_files = [f for f in old_files if f not in new and (t := _inside(out, f)) is not None
                          and (t.is_file() or t.is_symlink())]
            kept_folders, old_files, old_folders = old_folders, [f for f in old_files if f in new], set()
        with deferred_interrupt():
            # first the union: killed at any point from here, the next run still knows every file as its own
            write_manifest(out, {**manifest, entry: {"files": sorted({*old_files, *new, *kept_files}),
                                                     "folders": sorted(old_folders | kept_folders)}})
            _remove_files(out, old_files)
            folders = set()
            for name in new:
                for parent in reversed(list(Path(name).parents)[:-1]):
                    if not (out / parent).is_dir():
                        (out / parent).mkdir()
                        folders.add(str(parent))
                    elif str(parent) in old_folders:
                        folders.add(str(parent))
                os.replace(staging / name, out / name)
            _remove_empty_folders(out, old_folders - folders)
            entries = {c: e for c, e in manifest.items() if c not in replaces}
            entries[entry] = {"files": [*new, *sorted(kept_files)], "folders": sorted(folders | kept_folders)}
            if entry == self.command:  # a good run: its command's failure record is stale
                _remove_entry(out, entries.pop(failed_entry(self.command), None))
            write_manifest(out, entries)
            shutil.rmtree(staging, ignore_errors=True)
            self.published = True  # a Ctrl-C held back during the swap is raised after this: the results are in
        return [out / name for name in new]

    def discard(self) -> None:
        """Leave the folder as it was: the staging folder goes, and a folder this call made if it is empty."""
        if self.staging != Path():
            shutil.rmtree(self.staging, ignore_errors=True)
        self._unlock()
        self._remove_created()

    def _unlock(self) -> None:
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def _remove_created(self) -> None:
        remove_if_empty(self.created)


@contextlib.contextmanager
def results_folder(out: Path | str, command: str, *, option: str = "--out", expected: Iterable[str] = (),
                   replaces: Iterable[str] = (), accumulate: bool = False) -> Iterator[ResultsFolder]:
    """Open `out` for `command`'s results (checked now: OutputFolderError, exit 2; another command writing
    there: OutputFolderBusy, exit 3) and yield it; the results written into `.staging` are swapped in by
    `.publish()`, else the folder stays as it was. `replaces`: other commands whose earlier files this run's
    results make stale (run: animate's videos); `accumulate`: replace only the files of the new names."""
    folder = ResultsFolder(out, command, option, replaces, accumulate)
    folder.open(expected)
    try:
        yield folder
    finally:
        if not folder.published:
            folder.discard()
        folder._unlock()


def partial_path(target: Path) -> Path:
    """The temporary file of this process beside `target` (a file a command names: mjcf -o FILE)."""
    return target.with_name(f".{target.name}.{os.getpid()}.partial")


def remove_stale_partials(target: Path) -> None:
    """Remove the temporary files beside `target` whose process is gone (killed before it could clean up)."""
    with contextlib.suppress(OSError):
        for entry in target.parent.glob(f".{target.name}.*.partial"):
            pid = entry.name[len(target.name) + 2:-len(".partial")]
            if pid.isdigit() and not _alive(int(pid)) and entry.is_file():
                entry.unlink(missing_ok=True)


# Kernel file systems: they hold no folder of results (a mkdir there says "No such file or directory").
SYSTEM_FOLDERS = ("/proc", "/sys", "/dev")
# ... but /dev/shm is an ordinary tmpfs a user may write results into
WRITABLE_SYSTEM_FOLDERS = ("/dev/shm",)


def kernel_folder(path: Path) -> str | None:
    """The kernel's file system (/proc, /sys, /dev but /dev/shm) that `path` is in, None when it is in none."""
    resolved = Path(os.path.abspath(path))
    if any(resolved.is_relative_to(ok) for ok in WRITABLE_SYSTEM_FOLDERS):
        return None
    return next((system for system in SYSTEM_FOLDERS if resolved.is_relative_to(system)), None)


def unfit_folder(out: Path) -> str | None:
    """Why `out` cannot hold a results folder, in words that name the real cause (None: it may)."""
    resolved = Path(os.path.abspath(out))
    if resolved == Path(resolved.anchor):
        return "it is the file system's root: give a folder of its own (e.g. results)"
    if (system := kernel_folder(out)) is not None:
        return f"{system} is the kernel's file system, which holds no folder of results: give another folder"
    if out.is_symlink() and not out.exists():
        return (f"it is a symbolic link to {os.readlink(out)}, which does not exist: create that folder, or remove "
                "the link")
    return None


def out_path(text: str) -> Path:
    """The argparse type of every output option (--out, -o, --gif, RESULTS_DIR): an empty name is refused
    (Path('') would silently be the current folder)."""
    import argparse

    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name (it would be the current folder): give a folder or file")
    return Path(text)


def missing_folders(out: Path) -> list[Path]:
    """The folders of `out`'s path that do not exist yet, outermost first."""
    missing = []
    for folder in (out, *out.parents):
        if folder.exists() or folder.is_symlink():
            break
        missing.append(folder)
    return list(reversed(missing))


def remove_if_empty(folders: list[Path]) -> None:
    """Remove the folders (outermost first, as `missing_folders` gives them) a failed command made, innermost
    first, while they are empty."""
    for folder in reversed(folders):
        try:
            folder.rmdir()
        except OSError:
            break


@contextlib.contextmanager
def no_empty_folder_left(out: Path) -> Iterator[None]:
    """For a command with a staging of its own (generate, export-step): a failure or Ctrl-C leaves no empty
    folder that the command made."""
    made = missing_folders(out)
    try:
        yield
    except BaseException:
        remove_if_empty(made)
        raise
