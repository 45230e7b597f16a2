"""One writer per run folder: a flight (and a sweep's flight plus evaluation) claims its folder first.

Two processes flying the same run (two `sweep` calls over one run root, a `fly --resume` beside a
sweep) would both write its checkpoint, frames and maps and leave a result neither flew. The claim
is a file that appears under its name only where none is there (a hard link of a finished file), so
one process holds it; it names the host, the process and that process's start time. A claim left by
a killed process on this host (no such process, or the pid reused by a later one) is stale and taken
over; one from another host (a shared file system) cannot be checked from here, so it stands until
that process ends or the user deletes the file.
A process may claim a folder it already holds (the sweep claims, then the flight inside it).
"""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from flightrecon import procfs, run_folder
from flightrecon.errors import FlightReconError

_held: set[Path] = set()  # folders this process holds


class RunInUse(FlightReconError):
    """The run folder is claimed by another live process; the message names it and the lock file."""


def _start_ticks(pid: int) -> int | None:
    """The process's start time in clock ticks since boot (Linux /proc), or None where unknown."""
    fields = procfs.stat_fields(pid)
    return None if fields is None else int(fields[19])


def _me() -> dict:
    return {"host": socket.gethostname(), "pid": os.getpid(), "start": _start_ticks(os.getpid())}


def _alive_here(pid: int, start: int | None) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: it exists
        pass
    if procfs.is_zombie(pid):  # killed but not reaped: it flies nothing
        return False
    return start is None or _start_ticks(pid) in (None, start)


def holder(run_dir: str | Path) -> dict | None:
    """Which other process holds the run folder: {'host', 'pid', 'start'} of its live claim, or None
    (unclaimed, held by this process, or stale). An unreadable claim (a damaged file) counts as stale."""
    path = Path(run_dir) / run_folder.LOCK
    try:
        claim = json.loads(path.read_text())
        host, pid = str(claim["host"]), int(claim["pid"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if host != socket.gethostname():
        return claim
    if pid == os.getpid():
        return None
    return claim if _alive_here(pid, claim.get("start")) else None


def describe(claim: dict) -> str:
    return f"process {claim['pid']} on {claim['host']}"


@contextmanager
def claim(run_dir: str | Path) -> Iterator[None]:
    """Hold the run folder for the block; raises RunInUse when another live process holds it."""
    folder = Path(run_dir).resolve()
    if folder in _held:  # held by an outer block of this process, which lets it go
        yield
        return
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / run_folder.LOCK
    mine = folder / f"{run_folder.LOCK}.{socket.gethostname()}.{os.getpid()}"
    mine.write_text(json.dumps(_me()))  # complete before it appears under the lock's name (link)
    try:
        for _ in range(2):  # the second try follows the removal of a stale claim
            try:
                os.link(mine, path)  # fails where the name exists, on local and network file systems
                break
            except FileExistsError:
                other = holder(folder)
                if other is not None:
                    raise RunInUse(f"{folder} is being flown by {describe(other)} ({path}); wait for it to "
                                   f"end, or delete {path} if that process is gone") from None
                path.unlink(missing_ok=True)
        else:
            raise RunInUse(f"{folder}: another process claimed {path} at the same moment; try again")
    finally:
        mine.unlink()
    _held.add(folder)
    try:
        yield
    finally:
        _held.discard(folder)
        path.unlink(missing_ok=True)
