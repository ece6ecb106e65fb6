"""MAVLink routing between the flight controller's links, as an ArduPilot autopilot routes
(AP_MAVLink_routing; MAVLink's routing rules):

- every system/component heard is remembered with the link it was last heard on;
- a broadcast message (no target, or target system 0) goes out on every other link;
- a message for the FC itself (target system and component ours) stays here;
- a message for someone else goes out on the links where its target (component 0: any
  component of that system) was heard, never back on the link it came from; a target never
  heard is not forwarded.

The packet goes out as it came (same sender, sequence and signature). With one link there is
nothing to route. So a ground station on a second link sees the companion's STATUSTEXT and
M4_FAULT_STATUS, and the companion sees the ground station's commands for it.
"""

from __future__ import annotations

from m4.mavlink import FC_COMPONENT_ID, FC_SYSTEM_ID


class Router:
    def __init__(self, links, own: tuple[int, int] = (FC_SYSTEM_ID, FC_COMPONENT_ID)):
        self.links = links
        self.own = own
        self.forwarded = 0
        self._heard_on: dict[tuple[int, int], int] = {}       # (system, component) -> link index

    def forward(self, index: int, msgs) -> None:
        """Route the messages that arrived on link `index` to the other links."""
        if len(self.links) < 2:
            return
        for msg in msgs:
            self._heard_on[(msg.get_srcSystem(), msg.get_srcComponent())] = index
            packet = msg.get_msgbuf()
            for out in self._destinations(index, msg):
                self.links[out].write(packet)
                self.forwarded += 1

    def _destinations(self, index: int, msg) -> set[int]:
        system = getattr(msg, "target_system", 0)
        component = getattr(msg, "target_component", 0)
        if system == 0:
            return set(range(len(self.links))) - {index}
        if (system, component) == self.own:
            return set()
        return {link for (s, c), link in self._heard_on.items()
                if s == system and component in (0, c) and link != index}
