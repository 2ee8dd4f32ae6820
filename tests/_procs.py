"""A process's relatives as /proc tells them (Linux): the kill tests' walkers in one place."""

from __future__ import annotations

from pathlib import Path


def ppid_and_state(pid: int) -> tuple[int, str] | None:
    """``(parent pid, state letter)`` of ``pid``; None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()  # (the command name may hold spaces and parentheses)
    return int(fields[1]), fields[0]


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie has ended)."""
    info = ppid_and_state(pid)
    return info is not None and info[1] != "Z"


def descendants(pid: int, *, depth: int | None = None) -> set[int]:
    """The processes below ``pid``: its children (``depth`` 1), their children, ... (None: all)."""
    by_parent: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and (info := ppid_and_state(int(d.name))) is not None:
            by_parent.setdefault(info[0], []).append(int(d.name))
    out, todo = set(), [(pid, 0)]
    while todo:
        parent, level = todo.pop()
        for c in by_parent.get(parent, []) if depth is None or level < depth else ():
            if c not in out:
                out.add(c)
                todo.append((c, level + 1))
    return out


def cmdline(pid: int) -> bytes:
    """``pid``'s command line (NUL-separated; empty when it is gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""
