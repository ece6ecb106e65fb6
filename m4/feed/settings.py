"""How the feed reaches Zenoh: a Zenoh config file, or a mode and explicit endpoints.

In the companion's TOML configuration (all keys optional):

    [feed]
    enabled = true
    vehicle = "m4"                                   # keys m4/<vehicle>/<topic>
    zenoh_config = "/etc/m4/zenoh-companion.json5"   # a Zenoh config file (json5); or:
    mode = "peer"                                    # "peer" or "client", with
    connect = "tcp/127.0.0.1:7447"                   # an endpoint to connect to, and/or
    listen = "tcp/127.0.0.1:7448"                    # one to listen on (peer only)
    max_rate_hz = 20.0                               # per topic, over each topic's own rate; 0: every call

A Zenoh config file is used as written (scouting, interfaces, several endpoints,
everything). With explicit endpoints, scouting is off and the session listens only where `listen` says, so nothing
is opened that the file does not name.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from m4.feed.payloads import check_vehicle
from m4.toml_fields import ConfigError, Table

MODES = ("peer", "client")
DEFAULT_VEHICLE = "m4"
DEFAULT_MAX_RATE_HZ = 20.0
MAX_RATE_HZ_LIMIT = 100.0      # the companion publishes once a control step, at most 100 a second


@dataclass(frozen=True)
class FeedSettings:
    enabled: bool = True
    vehicle: str = DEFAULT_VEHICLE
    zenoh_config: Path | None = None
    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    max_rate_hz: float = DEFAULT_MAX_RATE_HZ

    def validate(self) -> None:
        """Raise ConfigError saying what is wrong (the caller adds where); a disabled feed needs nothing."""
        if not self.enabled:
            return
        try:
            check_vehicle(self.vehicle)
        except ValueError as e:
            raise ConfigError(str(e)) from None
        if self.max_rate_hz < 0:
            raise ConfigError(f"max_rate_hz must be >= 0, got {self.max_rate_hz:g}")
        if self.zenoh_config is not None:
            if self.connect or self.listen:
                raise ConfigError("give either zenoh_config or connect/listen endpoints, not both")
            return
        if self.mode not in MODES:
            raise ConfigError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.mode == "client" and (self.listen or not self.connect):
            raise ConfigError("client mode needs connect endpoints and cannot listen")
        if not (self.connect or self.listen):
            raise ConfigError("peer mode needs connect or listen endpoints (or a zenoh_config file)")


def parse_feed_settings(t: Table, base_dir: Path | None = None) -> FeedSettings:
    """Read a [feed] table; a relative zenoh_config path is taken from base_dir (the TOML's folder)."""
    enabled = t.boolean("enabled", True)
    zenoh_config = t.path("zenoh_config", base_dir)
    if zenoh_config is not None and t.has("mode"):
        raise ConfigError(f"{t.where}: give either zenoh_config or mode with endpoints, not both")
    settings = FeedSettings(
        enabled=enabled,
        vehicle=t.string("vehicle", DEFAULT_VEHICLE),
        zenoh_config=zenoh_config,
        mode=t.string("mode", "peer", choices=MODES),
        connect=_endpoint(t, "connect"),
        listen=_endpoint(t, "listen"),
        max_rate_hz=t.number("max_rate_hz", DEFAULT_MAX_RATE_HZ, lo=0.0, hi=MAX_RATE_HZ_LIMIT),
    )
    t.finish()
    try:
        settings.validate()
    except ConfigError as e:
        raise ConfigError(f"{t.where}: {e}") from None
    return settings


def _endpoint(t: Table, key: str) -> tuple[str, ...]:
    value = t.string(key, "")
    if value and "/" not in value:
        raise ConfigError(f"{t.where} {key}: an endpoint looks like tcp/HOST:PORT, got {value!r}")
    return (value,) if value else ()
