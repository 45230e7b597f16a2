"""A process's /proc/<pid>/stat (Linux), read in one place for the run lock and the viewer's teardown."""

from __future__ import annotations

from pathlib import Path


def stat_fields(pid: int) -> list[str] | None:
    """The stat fields after the command name (the name in parentheses may hold spaces): index 0 is
    the state (proc(5) field 3), 2 the process group, 19 the start time. None where unreadable: no
    such process, or no procfs."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text.rsplit(")", 1)[1].split()


def is_zombie(pid: int) -> bool:
    """Dead but not reaped. Where PID 1 does not reap orphans (some containers) a dead process stays
    so, and still answers kill(pid, 0)."""
    fields = stat_fields(pid)
    return fields is not None and fields[0] == "Z"


def group_members(pgid: int) -> list[int]:
    """The live (not zombie) processes of a process group; empty without procfs."""
    members = []
    for entry in Path("/proc").glob("[0-9]*"):
        fields = stat_fields(int(entry.name))
        if fields is not None and int(fields[2]) == pgid and fields[0] != "Z":
            members.append(int(entry.name))
    return members
