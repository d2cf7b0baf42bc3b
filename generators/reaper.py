"""A reaper for processes a driver starts but cannot take down when it is SIGKILLed (a local Ray's raylet, its
workers and agents): a small watcher process that notes the driver's descendants every ``PERIOD_S`` and, once
the driver is gone, SIGKILLs every one of them still alive (matched by pid and start time, so a reused pid is
never hit). Linux only (it reads ``/proc``); elsewhere ``start_reaper`` returns None.

Local pool workers need none of this: they take a parent-death signal themselves (``runner._die_with_parent``).
Ray's task workers die with their raylet, but its agents outlive the driver by a minute or more.

    python -m univtac_data.generators.reaper DRIVER_PID
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

PERIOD_S = 0.5


def _stat(pid: int) -> tuple[int, str] | None:
    """(parent pid, start time) of ``pid``, or None when it is gone or a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[1]), fields[19]) if fields[0] != "Z" else None


def descendants(root: int) -> dict[int, str]:
    """Every live descendant of ``root``: pid -> start time."""
    children: dict[int, list[tuple[int, str]]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            stat = _stat(int(entry))
            if stat is not None:
                children.setdefault(stat[0], []).append((int(entry), stat[1]))
    out: dict[int, str] = {}
    todo = [root]
    while todo:
        for pid, started in children.get(todo.pop(), []):
            if pid not in out:
                out[pid] = started
                todo.append(pid)
    return out


def watch(driver: int) -> None:
    me = os.getpid()
    seen: dict[int, str] = {}
    while os.getppid() == driver:
        seen.update({p: s for p, s in descendants(driver).items() if p != me})
        time.sleep(PERIOD_S)
    for pid, started in seen.items():
        stat = _stat(pid)
        if stat is not None and stat[1] == started:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def start_reaper() -> subprocess.Popen[bytes] | None:
    """Start a reaper for this process's descendants (stop it with ``stop_reaper`` on a normal exit)."""
    if not os.path.isdir("/proc/self"):
        return None
    return subprocess.Popen([sys.executable, "-m", "univtac_data.generators.reaper", str(os.getpid())],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def stop_reaper(reaper: subprocess.Popen[bytes] | None) -> None:
    if reaper is not None and reaper.poll() is None:
        reaper.kill()
        reaper.wait()


if __name__ == "__main__":
    watch(int(sys.argv[1]))
