"""`m4-sitl serve`: the simulated vehicle behind MAVLink links, in lockstep or in real time.

Lockstep (default, deterministic): at every control instant the FC sends its frame and the
simulation waits (wall clock) for the M4_SETPOINT answering that instant; the setpoint's
period_ms sets the next instant. Before the first setpoint the simulation waits at t = 0,
sending the frame again every `RESEND_S` so a companion that starts late still gets it. A
companion silent for `lockstep_timeout_s` is logged and the simulation goes on without
waiting, in the FC's failsafe, until a setpoint comes again.

In lockstep, what the FC says between two frames (the streams of the instants in between,
its own STATUSTEXTs) goes out with the next frame, in the same order, packed into as few
datagrams as fit: nobody can act on it sooner (the companion answers frames), and the
companion wakes once a control period instead of at every instant. Replies to what arrives
(TIMESYNC, command acknowledgements, the mode change a setpoint brings) go out at once; with
link emulation (below) every instant's datagram goes out at its instant, as the emulation
draws its losses per datagram.

Link delay and loss (`link`, sitl/links/emulation.py): the companion's link (the first URL)
is impaired in simulated time, in lockstep and in real time alike. With delay D each way and
loss p, in lockstep:
- every datagram the FC sends on it at instant t is lost with probability p, else delivered
  (at once in wall time: the companion cannot tell that from t + D);
- every datagram that arrives from it while the FC's clock is at t (e.g. the answer to frame
  t) is lost with probability p, else handled at t + 2 D on the FC's clock, in arrival order,
  first thing at that instant (so the FC's replies precede that instant's frame): setpoints,
  commands, M4_FAULT_STATUS and TIMESYNC requests alike (so the FC's TIMESYNC reply says
  tc1 = t + 2 D and the companion measures a lead of 2 D);
- the FC still waits at frame t for the setpoint answering it, but not for the answer to a
  frame it lost, and a setpoint lost on the way up counts as the answer (the FC knows what
  its link dropped); an arrived answer ends the wait though it acts only at t + 2 D.
The losses are drawn from `seed` (independently of the plant's noise): the same seed loses
the same frames and setpoints. Other links (a ground station's) are not impaired.

Real time (`realtime=True`): the simulated clock follows the wall clock; messages are handled
as they arrive (with `link`, 2 D later). Every packet in and out goes to the tlog when one is asked for. With several
links, what arrives on one is routed to the others as an autopilot does (sitl/fc/routing.py);
the FC's replies go to the link the message came on, its telemetry at each link's own rates
(sitl/vehicle.py).

At its end (the duration flown, or stopped) the FC says it shuts down: a HEARTBEAT with
MAV_STATE_POWEROFF on every link, so a companion reports the end of the flight, not a lost link.

A flood cannot stall the simulation: one poll reads at most `POLL_DATAGRAMS` datagrams per
link (the rest waits in the socket, and the kernel drops what does not fit), so the plant
and the telemetry streams keep their pace. A udpin link answers the paired companion's
address only (signed, with a key): nobody else can redirect the telemetry. With a key and
`signing_state_path`, the signing timestamps survive a restart (m4.mavlink.signing).

Parameters (PARAM_* protocol, sitl/fc/params.py) are answered to the companion and to ground
stations alike (only signed, with a key); what is set is kept in `params_path` and loaded
from it at the next start (m4/params_file.py).

A second sender claiming the companion's ids is reported by the FC (m4/mavlink/second_sender.py):
a packet signing refused (unsigned, badly signed, replayed), one that passed signing unsigned
(HEARTBEAT) though the key requires signatures, or one from another place (link and address)
while the companion's own is live. Without a key it is still obeyed: only signing refuses it.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from m4.airframe import Airframe, load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID
from m4.mavlink.link import UdpLink, wait_readable
from m4.mavlink.second_sender import OTHER_ADDRESS, PairedPlace, address_text
from m4.mavlink.signing import StreamTimestamps, refusal
from m4.mavlink.tlog import TlogWriter
from m4.params_file import ParamFile
from m4.toml_fields import ConfigError
from sitl.links.emulation import EmulatedLink, LinkEmulation
from sitl.fc.routing import Router
from m4.scenario import Scenario
from sitl.plant.truth import TruthRecorder
from sitl.vehicle import Vehicle, log

RESEND_S = 1.0
IDLE_PERIOD_MS = 20           # control instants in lockstep before any setpoint fixed the period
REALTIME_CHUNK_MS = 4
VIEWER_SYNC_S = 1.0 / 60.0
POLL_DATAGRAMS = 32           # per link and poll: bounded work per loop iteration


@dataclass(frozen=True)
class ServeOptions:
    scenario: Scenario
    mavlink_urls: tuple[str, ...] = ("udpout:127.0.0.1:14550",)
    realtime: bool = False
    viewer: bool = False
    tlog_path: Path | None = None
    signing_key: bytes | None = None
    seed: int = 0
    duration_s: float | None = None            # None: until interrupted
    lockstep_timeout_s: float = 5.0
    truth_log_path: Path | None = None         # the plant's true state (sitl.plant.truth), written on close
    companion_ids: tuple[int, int] = (FC_SYSTEM_ID, COMPANION_COMPONENT_ID)   # the paired companion
    signing_state_path: Path | None = None     # signing timestamps kept across restarts (with a key)
    link: LinkEmulation | None = None          # delay and loss on the first link (the companion's)
    params_path: Path | None = None            # the FC's parameters set over MAVLink, kept across restarts


class ServeError(RuntimeError):
    """The server cannot start (tlog not writable, no display for the viewer)."""


class Server:
    """Opens the links (LinkError on a bad URL or a port in use) and runs the vehicle."""

    def __init__(self, options: ServeOptions, airframe: Airframe | None = None):
        self.options = options
        try:
            self.vehicle = Vehicle(options.scenario, airframe or load_airframe(), options.seed,
                                   lockstep=not options.realtime, companion_ids=options.companion_ids,
                                   require_signed=options.signing_key is not None,
                                   params_file=ParamFile(options.params_path) if options.params_path else None,
                                   links=len(options.mavlink_urls))
        except ConfigError as e:
            raise ServeError(f"parameters: {e}") from None
        self._viewer = None
        self._viewer_synced = 0.0
        self._stop = False
        self.truth = TruthRecorder() if options.truth_log_path else None
        if self.truth is not None:
            self.vehicle.observers.append(self.truth.observe)
        self.links: list[UdpLink] = []
        self.emulated: EmulatedLink | None = None
        self.timestamps: StreamTimestamps | None = None
        self.companion_place = PairedPlace()
        try:
            self.tlog = TlogWriter(options.tlog_path) if options.tlog_path else None
        except OSError as e:
            raise ServeError(f"cannot write the tlog {options.tlog_path}: {e.strerror}") from None
        try:
            for i, url in enumerate(options.mavlink_urls):
                self.links.append(self._open_link(i, url))
                self.links[-1].peer_filter = self.vehicle.fc.from_companion
                self.links[-1].on_refused = partial(self._refused, i)
            if options.signing_key is not None and options.signing_state_path is not None:
                self.timestamps = StreamTimestamps([link.mav for link in self.links],
                                                   options.signing_state_path).keep_saving()
        except Exception:
            self.close()
            raise
        self.router = Router(self.links)
        if self.emulated is not None:
            self.vehicle.inbox = self

    def _open_link(self, i: int, url: str) -> UdpLink:
        o = self.options
        if i == 0 and o.link is not None:
            self.emulated = EmulatedLink(url, FC_SYSTEM_ID, FC_COMPONENT_ID, emulation=o.link, seed=o.seed,
                                         clock=lambda: self.vehicle.now_ms, lockstep=not o.realtime, tlog=self.tlog,
                                         key=o.signing_key)
            return self.emulated
        return UdpLink(url, FC_SYSTEM_ID, FC_COMPONENT_ID, tlog=self.tlog, key=o.signing_key, link_id=i)

    # -- plumbing --------------------------------------------------------------------------------
    def send(self, msgs, link: int | None = None) -> None:
        """To every link, or to link number `link`."""
        msgs = list(msgs)
        if msgs:
            for out in self.links if link is None else (self.links[link],):
                out.send_all(msgs)

    def poll(self) -> None:
        """Handle everything that has arrived, at the current simulated instant."""
        for i, link in enumerate(self.links):
            self._handle(i, link.receive_from(POLL_DATAGRAMS))

    def _where(self, i: int, sender) -> str:
        return address_text(sender) + (f" on link {i}" if len(self.links) > 1 else "")

    def _refused(self, i: int, sender, system: int, component: int, why: str) -> None:
        """A packet link i refused that claims an identity (UdpLink.on_refused)."""
        if (system, component) == self.vehicle.fc.companion_ids:
            self.vehicle.fc.second_sender(self._where(i, sender), why)

    def _watch_companion(self, i: int, datagrams) -> None:
        """Packets that passed the link claiming the companion's ids: unsigned where the key asks
        for signatures (a HEARTBEAT), or from another place while the companion's is live."""
        fc = self.vehicle.fc
        for sender, batch in datagrams:
            for msg in batch:
                if (msg.get_srcSystem(), msg.get_srcComponent()) != fc.companion_ids:
                    continue
                if not fc.from_companion(msg):
                    fc.second_sender(self._where(i, sender), refusal(self.options.signing_key, msg.get_msgbuf()))
                elif self.companion_place.other((i, sender)):
                    fc.second_sender(self._where(i, sender), OTHER_ADDRESS,
                                     f"the companion is at {self._where(*self.companion_place.place)}")

    def _handle(self, i: int, datagrams) -> None:
        self._watch_companion(i, datagrams)
        msgs = [msg for _, batch in datagrams for msg in batch]
        if msgs:
            # what the FC repeats as its own (the companion's critical texts) reaches the other links once: as the FC's
            self.router.forward(i, [msg for msg in msgs if self.vehicle.fc.relayed(msg) is None])
            self.vehicle.handle(msgs, self.send, i)

    # -- the emulated link's messages, as the vehicle's inbox (sitl/vehicle.py) -------------------
    def next_delivery_ms(self) -> int | None:
        return self.emulated.next_delivery_ms()

    def deliver_held(self) -> None:
        self._handle(0, self.emulated.deliver())

    def _answered(self, t_ms: int) -> bool:
        """Lockstep: the FC need not wait any longer at instant t_ms."""
        if self.emulated is not None:
            return self.emulated.answered(t_ms)
        sp = self.vehicle.fc.setpoint
        return sp is not None and sp.time_ms == t_ms

    def _answers(self) -> int:
        """How many setpoints have come so far (arrived on an emulated link, else accepted)."""
        if self.emulated is not None:
            return self.emulated.counters.setpoints
        return self.vehicle.fc.counters.setpoints_accepted

    def stop(self) -> None:
        """Ask the loop to end (from another thread) at its next instant."""
        self._stop = True

    def _ended(self) -> bool:
        end = self.options.duration_s
        return self._stop or (end is not None and self.vehicle.now_ms >= round(end * 1000))

    def _open_viewer(self) -> None:
        import glfw
        import mujoco.viewer

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if not glfw.init():      # MuJoCo would exit the process instead of raising
                raise ServeError("cannot open the MuJoCo viewer: no display (GLFW could not initialise)")
        try:
            self._viewer = mujoco.viewer.launch_passive(self.vehicle.plant.model, self.vehicle.plant.data)
        except Exception as e:  # noqa: BLE001 - no GL context etc.: whatever MuJoCo raises, in one line
            raise ServeError(f"cannot open the MuJoCo viewer: {e}") from None

    def _sync_viewer(self) -> None:
        if self._viewer is not None and time.monotonic() - self._viewer_synced >= VIEWER_SYNC_S:
            if not self._viewer.is_running():
                self._stop = True
                return
            self._viewer.sync()
            self._viewer_synced = time.monotonic()

    # -- the loops -------------------------------------------------------------------------------
    def run(self) -> None:
        if self.options.viewer:
            self._open_viewer()
        wall0, cpu0 = time.monotonic(), time.process_time()
        mode = "real time" if self.options.realtime else "lockstep"
        unsigned = "" if self.options.signing_key else "; MAVLink signing off (no --signing-key): anyone may command it"
        params = self.options.params_path
        kept = f"; parameters kept in {params}" if params else "; parameters set last this run (no --params)"
        log(f"serving {self.options.scenario.name!r} in {mode} on "
             + ", ".join(link.endpoint.url for link in self.links) + unsigned + kept)
        try:
            (self._run_realtime if self.options.realtime else self._run_lockstep)()
            self.send(self.vehicle.fc.power_off(self.vehicle.now_ms))      # a normal end: said, not a lost link
        finally:
            wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
            sim = self.vehicle.now_ms / 1000.0
            c = self.vehicle.fc.counters
            rejected = sum(link.signing_counters().rejected for link in self.links)
            reasons = ", ".join(f"{n} {reason}" for reason, n in sorted(c.dropped_by_reason.items()))
            log(f"stopped at t={sim:.3f} s after {wall:.1f} s wall ({sim / max(wall, 1e-9):.1f}x), "
                 f"CPU {cpu:.2f} s ({1e3 * cpu / max(sim, 1e-9):.0f} ms per simulated second); "
                 f"setpoints accepted {c.setpoints_accepted}, dropped {c.setpoints_dropped}"
                 f"{f' ({reasons})' if reasons else ''}; commands {c.commands_acked}; "
                 f"refused from others {c.refused_foreign}; unsigned/bad-signature packets rejected {rejected}; "
                 f"garbled {sum(link.bad_packets for link in self.links) - rejected}; "
                 f"from a second sender claiming the companion {self.vehicle.fc.second_sender.count}")
            if self.emulated is not None:
                log(f"link emulated ({self.options.link.describe()}): {self.emulated.counters.summary()}")

    def _run_realtime(self) -> None:
        v = self.vehicle
        wall0 = time.monotonic()
        v.start(self.send)
        while not self._ended():
            target_ms = v.now_ms + REALTIME_CHUNK_MS
            while True:
                self.poll()
                ahead_s = target_ms / 1000.0 - (time.monotonic() - wall0)
                if ahead_s <= 0.0:
                    break
                wait_readable(self.links, ahead_s)
            v.advance_to(target_ms, self.send)
            self._sync_viewer()

    def _run_lockstep(self) -> None:
        v, fc = self.vehicle, self.vehicle.fc
        v.start(self.send)
        held: list[list] = [[] for _ in self.links]      # what the FC says between two frames, per link

        def hold(msgs, link: int | None = None) -> None:
            for i in range(len(held)) if link is None else (link,):
                held[i].extend(msgs)
        send = self.send if self.emulated is not None else hold
        waiting = True
        while not self._ended():
            if waiting:
                if not self._await_setpoint(v.now_ms):
                    if self._stop:
                        return
                    from sitl.flights.flight_run import STALL_MARK   # here: serve must not load the flights' runner
                    log(f"t={v.now_ms / 1000:.3f} s: {STALL_MARK} {self.options.lockstep_timeout_s:g} s "
                         "(wall clock); going on without waiting, in the FC's failsafe")
                    waiting = False
            else:
                answers = self._answers()
                self.poll()
                waiting = self._answers() > answers
            period_ms = fc.setpoint.period_ms if fc.setpoint is not None else IDLE_PERIOD_MS
            v.advance_to(v.now_ms + period_ms, send, frame=True)
            for i, msgs in enumerate(held):
                self.send(msgs, i)
                msgs.clear()
            self._sync_viewer()

    def _await_setpoint(self, t_ms: int) -> bool:
        """Wait for the setpoint answering instant `t_ms`; False after the lockstep timeout."""
        start = time.monotonic()
        deadline = start + self.options.lockstep_timeout_s
        resend_at = start + RESEND_S
        while True:
            self.poll()
            if self._answered(t_ms):
                return True
            now = time.monotonic()
            if now >= deadline or self._stop:
                return False
            if now >= resend_at:
                self.send(self.vehicle.current_frame())
                resend_at += RESEND_S
            self._sync_viewer()
            wait_readable(self.links, min(deadline, resend_at, now + 0.1) - now)

    def close(self) -> None:
        if self.timestamps is not None:
            self.timestamps.close()
            self.timestamps = None
        for link in self.links:
            link.close()
        if self.tlog is not None:
            self.tlog.close()
        if self.truth is not None:
            if self.truth.dropped:
                log(f"truth log: kept the last {len(self.truth.truth().time_s)} samples, "
                    f"dropped the first {self.truth.dropped}")
            self.truth.save(self.options.truth_log_path)
            self.truth = None
        if self._viewer is not None:
            self._viewer.close()
