"""Real-time scheduling for the control loop (`[control] realtime_priority`, `[control] cpu`).

`use_realtime(priority)` puts the calling thread, the run loop, in Linux's SCHED_FIFO class
at `priority` (1..99; 0 leaves it as it is): it then runs whenever it is ready, ahead of every
normal process, so a busy computer delays a control step by a context switch, not by a time
slice. Only this thread: the feed's threads, started before, keep their normal priority; the
processes it starts later (a compiler for a changed NMPC) do not inherit the class
(SCHED_RESET_ON_FORK). A runaway loop cannot take the machine: the NMPC stops iterating at
its time budget, and the kernel leaves others 5 % of each second by default
(kernel.sched_rt_runtime_us; deploy/README.md, "Priority").

Where the platform has no SCHED_FIFO, or the process may not use it (neither CAP_SYS_NICE nor
an RLIMIT_RTPRIO of at least `priority`: the unit's LimitRTPRIO), it says so in one line and
the companion flies on at normal priority.

`use_cpu(cpu)`, called before any thread is started, keeps the whole process on that CPU (None:
any): the run loop and every thread started after it (the feed's, the flight log's, the signing
timestamps'), as the unit's CPUAffinity= does. What it moves, and what not, is measured in
docs/performance.md, "Paced by the wall clock". A CPU this process may not run on is refused
(ConfigError, before the NMPC is built); a platform that cannot pin says so in one line and the
companion flies on.
"""

from __future__ import annotations

import logging
import os

from m4.toml_fields import ConfigError

log = logging.getLogger("m4-companion")

PRIORITY_MAX = 99           # SCHED_FIFO's range is 1..99 on Linux; 0 here: off


def use_realtime(priority: int) -> bool:
    """SCHED_FIFO at `priority` for the calling thread; True when it is in it (one log line either way)."""
    if priority == 0:
        return False
    if not hasattr(os, "sched_setscheduler"):
        log.warning("real-time priority %d asked for, but this platform has no SCHED_FIFO: flying at normal "
                    "priority", priority)
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except OSError as e:
        log.warning("real-time priority %d not granted (%s; %s): flying at normal priority", priority,
                    e.strerror or e, _permission_hint())
        return False
    log.info("control loop at real-time priority %d (SCHED_FIFO)", priority)
    return True


def use_cpu(cpu: int | None) -> bool:
    """The calling thread, and every thread it starts from now on, on `cpu` alone (None: left as
    it is); True when they are (one log line). ConfigError naming [control] cpu when this process
    may not run on it."""
    if cpu is None:
        return False
    if not hasattr(os, "sched_setaffinity"):
        log.warning("CPU %d asked for, but this platform cannot pin a process: the companion runs on any", cpu)
        return False
    usable = os.sched_getaffinity(0)
    if cpu not in usable:
        raise ConfigError(f"[control] cpu {cpu}: not a CPU this process may run on "
                          f"({', '.join(map(str, sorted(usable)))})")
    os.sched_setaffinity(0, {cpu})
    log.info("the companion on CPU %d", cpu)
    return True


def _permission_hint() -> str:
    import resource

    limit = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    shown = "unlimited" if limit == resource.RLIM_INFINITY else str(limit)
    return f"RLIMIT_RTPRIO is {shown}; the systemd unit's LimitRTPRIO= or CAP_SYS_NICE grants it"
