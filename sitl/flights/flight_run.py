"""One flight: the SITL and the companion as two processes talking MAVLink 2 over loopback UDP.

`run_flight` writes into the flight's folder:
- scenario.toml: the scenario file flown, byte for byte;
- companion.toml: the companion's configuration for this flight (controller variant, link,
  feed, the fault detector's settings the flight asks for; in lockstep no wall-clock time
  budget for the NMPC, so that the flight does not depend on the machine's load); the
  companion reads the scenario's [mission] from scenario.toml;
- mavlink.key: the flight's own signing key, new for each flight: both ends sign and check
  everything, as on the robot (docs/authority.md); their signing timestamps beside it;
- flight.tlog (every packet both ways), truth.npz (the plant's true state, sitl.plant.truth),
  feed.jsonl (the companion's Zenoh feed), sitl.log and companion.log (their stderr),
  companion-log/flight-*.tlog (the companion's own flight log: its side of the link and its
  decisions, companion/flight_log.py).

With `link` (delay, loss) the companion's link is impaired both ways: in lockstep by the SITL
itself, in simulated time (`m4-sitl serve --link-delay-ms --link-loss`, sitl/links/emulation.py:
deterministic, the losses drawn from the seed, whatever the machine's load); with `realtime`
through a loopback proxy (sitl/links/netem_proxy.py) on the wall clock, as a real link would be.

Order: the feed recorder listens, the companion starts, and so does the SITL alongside
(`m4-sitl serve --start-fd`: it builds its plant and opens its link while the companion builds
its NMPC, then waits); the companion opens its link and says so on a pipe (`m4-companion run
--ready-fd`), the SITL is told to start, flies the scenario's duration and exits; the companion
is then stopped with SIGTERM. Each flight takes its own free loopback ports, so flights can run side
by side. Anything that keeps the flight from starting raises FlightError with one line.

The two are new processes (`python -m companion.cli run ...`, `python -m sitl.cli serve ...`:
`start_process`), or whatever `start` makes of the same command lines: campaigns fork them from
pre-loaded parents (sitl/flights/forks.py).
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import random
import re
import select
import signal
import socket
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from m4.airframe import load_airframe
from m4.fork_server import Run
from m4.mavlink.signing import write_new_key
from sitl.flights.feed_recorder import FeedRecorder
from sitl.links.emulation import LinkEmulation
from sitl.links.netem_proxy import Impairment, Netem
from m4.scenario import Scenario

CONTROLLERS = ("nmpc", "fixed-posture")
VEHICLE = "m4"
COMPANION_START_TIMEOUT_S = 300.0     # a first start compiles the NMPC
STOP_TIMEOUT_S = 10.0
LOCKSTEP_TELEMETRY_TIMEOUT_S = 10.0   # lockstep: the companion's [link] telemetry_timeout_s, its largest
STALL_MARK = "no setpoint for"        # sitl/serve.py logs it when its lockstep wait runs out; read here
POLL_S = 0.2
LOWEST_PICKED_PORT = 10000            # free_port: outside the ephemeral range, above the well-known services
EPHEMERAL_RANGE = Path("/proc/sys/net/ipv4/ip_local_port_range")
DEFAULT_EPHEMERAL_RANGE = (32768, 65535)
HIGHEST_PORT = 65535
PORT_PICK_ATTEMPTS = 100
PORT_ATTEMPTS = 3                     # flights started again on a new port when another pick took it first
PORT_IN_USE = os.strerror(errno.EADDRINUSE)   # the companion's one line when its port is taken
_PREFIX = re.compile(r"^m4-[a-z]+: (error: )?")


class FlightError(RuntimeError):
    """The flight could not start or its processes failed (one line, for the user)."""


class PortTaken(FlightError):
    """The companion's port was taken between its pick and its bind (another flight's pick)."""


@dataclass(frozen=True)
class FlightOptions:
    controller: str = "nmpc"              # "fixed-posture": the NMPC with every hip pinned at nominal
    seed: int = 0                         # the SITL's sensor noise
    realtime: bool = False
    viewer: bool = False
    port: int | None = None               # loopback UDP port of the companion's MAVLink link; None: a free one
    record_feed: bool = True
    rate_hz: float | None = None          # the companion's control rate; None: the companion's default
    link: LinkEmulation | None = None     # delay and loss between the SITL and the companion
    companion_priority: int = 0           # the companion's [control] realtime_priority (SCHED_FIFO; 0: normal)
    sitl_priority: int = 0                # the SITL's SCHED_FIFO priority (0: normal), the FC's own hardware standing in
    companion_cpus: frozenset[int] = frozenset()   # the CPUs the companion's threads may run on (empty: any)
    sitl_cpus: frozenset[int] = frozenset()        # the SITL's (empty: any)
    feed_rate_hz: float = 0.0             # the companion's [feed] max_rate_hz: 0 records every topic at every step
                                          # (the metrics' NMPC figures need every solve); 20: the robot's default
    fault_detector: tuple[tuple[str, float], ...] = ()   # the companion's [fault_detector] settings (name, value)
    lockstep_timeout_s: float = 5.0       # lockstep: the SITL's wall-clock wait for a setpoint before its failsafe

    def link_conditions(self) -> dict:
        """The link's impairment and how it was made: "lockstep" (emulated in simulated time by
        the SITL), "proxy" (sitl/links/netem_proxy.py, real time) or "none"."""
        link = self.link or LinkEmulation()
        mode = "none" if self.link is None else "proxy" if self.realtime else "lockstep"
        return {"delay_ms": link.delay_ms, "loss": link.loss, "mode": mode}


COMPANION, SITL = "companion.cli", "sitl.cli"   # the two programs of a flight, as `python -m` runs them
Process = subprocess.Popen | Run                 # a program started: waited for, polled and signalled
Start = Callable[[str, list[str], Path, tuple[str, int]], Process]   # (program, args, stderr's log, pass_fd)
COMPANION_LOG_DIR = "companion-log"      # the companion's own flight log, in the flight's folder
SIGNING_KEY = "mavlink.key"              # both ends', in the flight's folder


class FlightFiles:
    """Where a flight's files are, in its folder."""

    def __init__(self, out_dir: Path):
        self.out_dir = Path(out_dir)
        self.scenario = self.out_dir / "scenario.toml"
        self.companion_config = self.out_dir / "companion.toml"
        self.signing_key = self.out_dir / SIGNING_KEY
        self.tlog = self.out_dir / "flight.tlog"
        self.truth = self.out_dir / "truth.npz"
        self.feed = self.out_dir / "feed.jsonl"
        self.sitl_log = self.out_dir / "sitl.log"
        self.companion_log = self.out_dir / "companion.log"
        self.companion_tlogs = self.out_dir / COMPANION_LOG_DIR
        self.metrics = self.out_dir / "metrics.json"


def start_process(program: str, args: list[str], log_path: Path, pass_fd: tuple[str, int] | None = None
                  ) -> subprocess.Popen:
    """`python -m PROGRAM ARGS [OPTION FD]` as a new process, stderr to `log_path`; `pass_fd`:
    (OPTION, FD), the descriptor passed to it and named by the option."""
    fds = () if pass_fd is None else (pass_fd[1],)
    named = [] if pass_fd is None else [pass_fd[0], str(pass_fd[1])]
    with log_path.open("w") as log:
        return subprocess.Popen([sys.executable, "-m", program, *args, *named], stdout=subprocess.DEVNULL,
                                stderr=log, stdin=subprocess.DEVNULL, pass_fds=fds)


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port on 127.0.0.1 free now, for a process started next to bind. Picked outside the
    kernel's ephemeral range: every socket bound to port 0 (the SITL's own end of its udpout link,
    Zenoh's, any other program's) gets its port from that range, so between this pick and the bind
    only another explicit pick could take it (a port the kernel had handed out and taken back was
    once given to the SITL's own socket before the companion bound it); a parallel flight's pick
    can, and run_flight then starts the flight again on a new one."""
    ports = pickable_ports()
    if not ports:
        start, end = ephemeral_port_range()
        raise FlightError(f"no port on 127.0.0.1 to pick: the kernel's ephemeral range {start}-{end} "
                          f"covers every port from {LOWEST_PICKED_PORT} up")
    pick = random.SystemRandom()
    for _ in range(PORT_PICK_ATTEMPTS):
        port = ports[pick.randrange(len(ports))]
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise FlightError(f"no free port on 127.0.0.1 from {LOWEST_PICKED_PORT} up outside the kernel's ephemeral "
                      f"range after {PORT_PICK_ATTEMPTS} tries")


def pickable_ports() -> list[int]:
    """The ports free_port picks from: LOWEST_PICKED_PORT and up, outside the kernel's ephemeral range."""
    start, end = ephemeral_port_range()
    return [*range(LOWEST_PICKED_PORT, min(start, HIGHEST_PORT + 1)),
            *range(max(end + 1, LOWEST_PICKED_PORT), HIGHEST_PORT + 1)]


def ephemeral_port_range() -> tuple[int, int]:
    """The kernel's ephemeral range, first and last port (Linux: ip_local_port_range; elsewhere
    IANA's 49152-65535, of which Linux's default 32768-60999 is the safe side below)."""
    try:
        start, end = (int(word) for word in EPHEMERAL_RANGE.read_text().split()[:2])
    except (OSError, ValueError):
        return DEFAULT_EPHEMERAL_RANGE
    return start, end


def check_port_free(port: int) -> None:
    if not 1 <= port <= 65535:
        raise FlightError(f"UDP port must be 1..65535, got {port}")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError as e:
            raise FlightError(f"UDP port {port} on 127.0.0.1 is not free: {e.strerror}") from None


def make_output_dir(path: Path) -> None:
    """Create the output folder `path`; FlightError in one line if it cannot be."""
    if path.exists() and not path.is_dir():
        raise FlightError(f"--out {path}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FlightError(f"--out {path}: cannot create the folder ({e.strerror or e})") from None


def companion_config_text(options: FlightOptions, mavlink_port: int, feed_port: int | None) -> str:
    rate = [] if options.rate_hz is None else [f"rate_hz = {options.rate_hz:g}"]
    priority = [f"realtime_priority = {options.companion_priority}"] * bool(options.companion_priority)
    link_timeout = [] if options.realtime else [
        "# lockstep: the FC's clock waits for our answers, so a wall-clock silence is the machine's load, not a",
        "# lost link (the SITL's own wait, --lockstep-timeout, says when it stalled)",
        f"telemetry_timeout_s = {LOCKSTEP_TELEMETRY_TIMEOUT_S:g}"]
    lines = ["# The companion's configuration for this flight (written by m4-sitl fly).",
             "[control]", *rate, *priority, "", "[link]",
             f'fc_url = "udpin:127.0.0.1:{mavlink_port}"', f'signing_key_file = "{SIGNING_KEY}"', *link_timeout, "",
             "[log]", f'dir = "{COMPANION_LOG_DIR}"', ""]
    nmpc = []
    if not options.realtime:
        nmpc += ["# lockstep: the FC waits for every answer, so a wall-clock time budget would only bring the",
                 "# machine's load into the flight (max_iterations still bounds every solve)",
                 "time_budget_share = 0.0"]
    if options.controller == "fixed-posture":
        nominal_deg = math.degrees(load_airframe().nominal_hip_rad)
        nmpc += ["# the fixed-posture variant: every hip pinned at the nominal angle", f"fixed_hip_deg = {nominal_deg:.12g}"]
    if nmpc:
        lines += ["[nmpc]", *nmpc, ""]
    if options.fault_detector:
        lines += ["[fault_detector]", *(f"{name} = {value!r}" for name, value in options.fault_detector), ""]
    if feed_port is not None:
        lines += ["[feed]", f'vehicle = "{VEHICLE}"', 'mode = "peer"', f'connect = "tcp/127.0.0.1:{feed_port}"',
                  f"max_rate_hz = {options.feed_rate_hz:g}", ""]
    return "\n".join(lines)


def _last_line(path: Path) -> str:
    """The last thing a process said, without its own "m4-...: error:" prefix."""
    lines = [ln for ln in path.read_text(errors="replace").splitlines() if ln.strip()] if path.exists() else []
    return _PREFIX.sub("", lines[-1]) if lines else "(no output)"


def _stop(proc: Process) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_flight(scenario: Scenario, scenario_text: str, out_dir: Path, options: FlightOptions = FlightOptions(),
               progress: Callable[[float], None] | None = None, start: Start = start_process) -> FlightFiles:
    """Fly `scenario` (its file's text: `scenario_text`); `progress(t_s)` is called with the
    newest simulated time the feed has shown, about every POLL_S wall seconds; `start` starts
    the companion and the SITL (each a new process by default)."""
    if options.controller not in CONTROLLERS:
        raise FlightError(f"unknown controller {options.controller!r}; choose from {', '.join(CONTROLLERS)}")
    if options.port is not None:
        check_port_free(options.port)
    files = FlightFiles(Path(out_dir))
    make_output_dir(files.out_dir)
    files.scenario.write_text(scenario_text)
    files.signing_key.unlink(missing_ok=True)
    write_new_key(files.signing_key)
    def attempt() -> FlightFiles:
        return _fly(scenario, scenario_text, files, options, progress, start, options.port or free_port())
    for _ in range(PORT_ATTEMPTS - 1):
        try:
            return attempt()
        except PortTaken:
            if options.port is not None:             # the user's port: theirs to free
                raise
    return attempt()


def _fly(scenario: Scenario, scenario_text: str, files: FlightFiles, options: FlightOptions,
         progress: Callable[[float], None] | None, start: Start, port: int) -> FlightFiles:
    """One attempt of run_flight on the companion's MAVLink `port`."""
    with contextlib.ExitStack() as stack:
        recorder = None
        feed_port = None
        if options.record_feed:
            feed_port = free_port(socket.SOCK_STREAM)
            recorder = FeedRecorder(files.feed, f"tcp/127.0.0.1:{feed_port}", VEHICLE)
            stack.callback(recorder.close)
        files.companion_config.write_text(companion_config_text(options, port, feed_port))
        args = ["run", "--config", str(files.companion_config)]
        if "mission" in tomllib.loads(scenario_text):          # none: hold where the flight starts
            args += ["--mission", str(files.scenario)]
        ready_r, ready_w = os.pipe()
        stack.callback(os.close, ready_r)
        try:
            companion = _start(stack, start(COMPANION, args, files.companion_log, ("--ready-fd", ready_w)))
        finally:
            os.close(ready_w)                    # the companion holds the only writing end now
        if options.companion_cpus:
            pin(companion.pid, options.companion_cpus, "the companion")
        sitl_port = port
        if options.link is not None and options.realtime:
            impairment = Impairment(delay_ms=options.link.delay_ms, loss=options.link.loss)
            proxy = Netem(("127.0.0.1", 0), ("127.0.0.1", port), impairment, seed=options.seed,
                          duration_s=2 * scenario.duration_s + 60.0).start()
            stack.callback(proxy.close)
            sitl_port = proxy.listen_port
        args = ["serve", "--scenario", str(files.scenario),
                "--mavlink", f"udpout:127.0.0.1:{sitl_port}", "--duration", f"{scenario.duration_s:g}",
                "--tlog", str(files.tlog), "--truth-log", str(files.truth), "--seed", str(options.seed),
                "--signing-key", str(files.signing_key)]
        if not options.realtime:
            args += ["--lockstep-timeout", f"{options.lockstep_timeout_s:g}"]
        if options.link is not None and not options.realtime:
            args += ["--link-delay-ms", f"{options.link.delay_ms:g}", "--link-loss", f"{options.link.loss:g}"]
        args += ["--realtime"] * options.realtime + ["--viewer"] * options.viewer
        # The SITL builds its plant while the companion builds its NMPC, and serves once told to.
        start_r, start_w = os.pipe()
        try:
            sitl = _start(stack, start(SITL, args, files.sitl_log, ("--start-fd", start_r)))
        finally:
            os.close(start_r)
        stack.callback(os.close, start_w)      # first on the way out: a SITL still waiting reads the end, exits
        if options.sitl_priority:
            _real_time(sitl, options.sitl_priority)
        if options.sitl_cpus:
            pin(sitl.pid, options.sitl_cpus, "the SITL")
        _await_ready(companion, ready_r, files.companion_log)
        _say_start(start_w)
        while not _exited(sitl, POLL_S):       # at once when it exits, not at the next poll
            if progress is not None and recorder is not None and recorder.latest_t_s is not None:
                progress(recorder.latest_t_s)
        if sitl.returncode != 0:
            raise FlightError(f"the SITL stopped with exit code {sitl.returncode}: {_last_line(files.sitl_log)}")
        if companion.poll() is not None:
            raise FlightError(f"the companion stopped during the flight: {_last_line(files.companion_log)}")
    return files


def stalled(files: FlightFiles) -> bool:
    """Whether the SITL's lockstep wait for a setpoint ran out in this flight (its FC then flew its
    failsafe): a flight the machine's load, not the software, decided."""
    return files.sitl_log.exists() and STALL_MARK in files.sitl_log.read_text(errors="replace")


def _start(stack: contextlib.ExitStack, proc: Process) -> Process:
    stack.callback(_stop, proc)
    return proc


def _exited(proc: Process, within_s: float) -> bool:
    try:
        proc.wait(within_s)
    except subprocess.TimeoutExpired:
        return False
    return True


def _say_start(fd: int) -> None:
    """Tell the waiting SITL to serve (a SITL that has stopped already is found stopped after)."""
    with contextlib.suppress(BrokenPipeError):
        os.write(fd, b"start\n")


def _real_time(proc: Process, priority: int) -> None:
    """SCHED_FIFO for the SITL just started, every thread of it: a SITL forked from a
    pre-loaded parent (sitl/flights/forks.py) may have started its signing-timestamps thread
    already (sitl/serve.py), and a thread takes its policy from the one that starts it."""
    real_time(proc.pid, priority, "the SITL")


def real_time(pid: int, priority: int, who: str | None = None) -> None:
    """Every thread of process `pid` in SCHED_FIFO at `priority`, or back to normal with 0.
    FlightError naming `who` (default: the process)."""
    try:
        policy = os.SCHED_FIFO if priority else os.SCHED_OTHER
        _each_thread(pid, lambda tid: os.sched_setscheduler(tid, policy, os.sched_param(priority)))
    except (AttributeError, OSError) as e:
        raise FlightError(f"cannot give {who or f'process {pid}'} real-time priority {priority}: "
                          f"{getattr(e, 'strerror', None) or e}") from None


def pin(pid: int, cpus: frozenset[int], who: str) -> None:
    """Every thread of process `pid` on `cpus` (the ones it starts later inherit it): to measure
    what the CPUs' placement does (python -m benchmarks.fly --companion-cpus/--sitl-cpus).
    FlightError naming `who`."""
    try:
        _each_thread(pid, lambda tid: os.sched_setaffinity(tid, cpus))
    except (AttributeError, OSError) as e:
        raise FlightError(f"cannot pin {who} to CPU {','.join(map(str, sorted(cpus)))}: "
                          f"{getattr(e, 'strerror', None) or e}") from None


def _each_thread(pid: int, apply: Callable[[int], None]) -> None:
    """`apply` to every thread of process `pid`, listed again until none has appeared meanwhile
    (one started before its starter was changed keeps the old setting)."""
    done: set[str] = set()
    while todo := set(os.listdir(f"/proc/{pid}/task")) - done:
        for tid in sorted(todo):
            with contextlib.suppress(ProcessLookupError):       # a thread that has ended since
                apply(int(tid))
        done |= todo


def _await_ready(proc: Process, ready_fd: int, log_path: Path) -> None:
    """Until the companion writes its ready line to the pipe; end of file first means it stopped."""
    deadline = time.monotonic() + COMPANION_START_TIMEOUT_S
    while not select.select([ready_fd], [], [], POLL_S)[0]:
        if time.monotonic() > deadline:
            raise FlightError(f"the companion was not ready within {COMPANION_START_TIMEOUT_S:g} s")
    if not os.read(ready_fd, 4096):
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(STOP_TIMEOUT_S)            # its last words are in its log once it has exited
        said = _last_line(log_path)
        raise (PortTaken if PORT_IN_USE in said else FlightError)(f"the companion did not start: {said}")
