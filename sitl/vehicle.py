"""The simulated vehicle: the MuJoCo plant, its flight controller and the scenario's faults
on one simulated clock (integer milliseconds since the scenario's t = 0).

No sockets and no wall clock here: `advance_to()` steps the physics from event to event (FC
ticks, telemetry streams, scheduled faults) and hands every message the FC emits on the way
to `send`; `handle()` feeds it received messages at the current instant. sitl/serve.py
paces it (lockstep or real time) and moves the bytes. With several links, `send(msgs, link)`
sends to one of them: its telemetry (each link has its own stream rates), the replies to a
message (to the link it came on: a ground station does not hear the acks meant for the
companion), and the companion's critical STATUSTEXT the FC repeats as its own (to the other
links); `send(msgs)` to all of them. An `inbox` (a delayed link) is stepped
to as well: what it holds for an instant is handed over first thing at that instant, so its
replies go out before that instant's telemetry.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable
from typing import Protocol

from m4.airframe import Airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.param_service import ParamService
from m4.params_file import ParamFile
from m4.scenario import Scenario
from m4.sensor_profiles import PROFILES
from sitl.fc.esc_telemetry import EscTelemetry
from sitl.fc.estimator import Estimator
from sitl.fc.flight_controller import TICK_MS, FlightController
from sitl.fc.params import fc_params
from sitl.plant.faults import FaultSchedule, describe
from sitl.plant.mujoco_plant import Plant
from sitl.fc.streams import FRAME
from sitl.plant.truth import DEFAULT_PERIOD_MS as OBSERVED_GRID_MS

Send = Callable[..., None]         # send(msgs): on every link; send(msgs, link): on that one


class Inbox(Protocol):
    """Messages held for later instants (sitl/links/emulation.py through sitl/serve.py)."""

    def next_delivery_ms(self) -> int | None: ...      # when the next is due (None: none held)

    def deliver_held(self) -> None: ...                # hand the FC what is due now


def log(text: str) -> None:
    """One line on stderr, prefixed like every message of the SITL process."""
    print(f"m4-sitl: {text}", file=sys.stderr, flush=True)


class Vehicle:
    def __init__(self, scenario: Scenario, airframe: Airframe, seed: int = 0, lockstep: bool = False,
                 companion_ids: tuple[int, int] = (FC_SYSTEM_ID, COMPANION_COMPONENT_ID), require_signed: bool = False,
                 params_file: ParamFile | None = None, links: int = 1):
        """params_file: the FC's parameters set over MAVLink, loaded here (ConfigError on a bad
        entry) and kept there (None: they last this run); links: how many links the FC has."""
        self.scenario = scenario
        sensors = PROFILES.get(scenario.sensors.profile)       # None: "ideal", the measured state as it is
        self.plant = Plant(airframe, scenario.plant, start_ned_m=scenario.start.ned_m,
                           start_yaw_rad=scenario.start.yaw_rad, seed=seed, wind=scenario.wind, sensors=sensors)
        estimator = None if sensors is None else Estimator(sensors, airframe.gravity_m_s2, scenario.start.ned_m,
                                                           scenario.start.yaw_rad)
        options = scenario.plant
        esc = EscTelemetry(airframe, TICK_MS, noise=options.sensor_noise, seed=seed) if options.esc_telemetry else None
        self.fc = FlightController(airframe, self.plant, lockstep=lockstep, companion_ids=companion_ids,
                                   require_signed=require_signed, log=log, esc=esc, estimator=estimator, links=links)
        self.links = links
        self.now_ms = 0
        self.fc.params = ParamService(fc_params(self.fc, lambda: self.now_ms), FC_SYSTEM_ID, FC_COMPONENT_ID, "FC",
                                      params_file, log)
        if params_file is not None:
            params_file.load(self.fc.params.table)
        self._faults = FaultSchedule(scenario.faults)
        self.observers: list[Callable[[int, Plant], None]] = []     # called at every simulated instant
        self.inbox: Inbox | None = None

    def start(self, send: Send) -> None:
        """The FC wakes up at t = 0 (failsafe HOLD until setpoints come) and sends its first frame."""
        self._at_instant(send, frame=True)

    def advance_to(self, t_ms: int, send: Send, frame: bool = False) -> None:
        """Simulate up to `t_ms`; with `frame`, the lockstep frame goes out at `t_ms`. Every
        instant on the OBSERVED_GRID_MS grid is one, so the observers (the truth log) sample the
        same instants whatever the streams' timing (which depends on when, in wall-clock time, a
        MAV_CMD_SET_MESSAGE_INTERVAL came)."""
        while self.now_ms < t_ms:
            grid = (self.now_ms // OBSERVED_GRID_MS + 1) * OBSERVED_GRID_MS
            nxt = min(self.fc.next_event_ms(self.now_ms), t_ms, grid)
            if (fault_ms := self._faults.next_ms()) is not None:
                nxt = min(nxt, max(fault_ms, self.now_ms + 1))
            if self.inbox is not None and (due := self.inbox.next_delivery_ms()) is not None:
                nxt = min(nxt, max(due, self.now_ms + 1))
            self.plant.step((nxt - self.now_ms) / 1000.0)
            self.now_ms = nxt
            self._at_instant(send, frame=frame and nxt == t_ms)

    def _at_instant(self, send: Send, frame: bool) -> None:
        for fault, ends in self._faults.due(self.now_ms):
            self.fc.set_rotor_loss(fault.rotor, 0.0 if ends else fault.loss, fault.kind)
            log(f"t={self.now_ms / 1000:.3f} s: {describe(fault, ends)}")
        if self.inbox is not None:
            self.inbox.deliver_held()
        if self.now_ms % TICK_MS == 0:
            self.fc.tick(self.now_ms)
        if said := self.fc.take_outbox():
            send(said)
        for link in range(self.links):
            if streams := self.fc.telemetry(self.now_ms, frame=frame, link=link):
                self._send_on(send, link, streams)
        for observe in self.observers:
            observe(self.now_ms, self.plant)

    def handle(self, msgs: Iterable[mavlink.MAVLink_message], send: Send, link: int = 0) -> None:
        """Messages that arrived on link `link`."""
        for msg in msgs:
            self._send_on(send, link, self.fc.handle(msg, self.now_ms, link))
            relayed = self.fc.relayed(msg)
            if relayed is not None:
                for other in range(self.links):
                    if other != link:
                        send([relayed], other)
        send(self.fc.take_outbox())

    def _send_on(self, send: Send, link: int, msgs) -> None:
        if self.links == 1:
            send(msgs)
        else:
            send(msgs, link)

    def current_frame(self) -> list[mavlink.MAVLink_message]:
        """HEARTBEAT and the frame at the current instant again (lockstep, while waiting)."""
        snap = self.fc.snapshot(self.now_ms)
        build = self.fc.telemetry_builder.build
        return [build(i, snap) for i in (mavlink.MAVLINK_MSG_ID_HEARTBEAT, *FRAME)]

