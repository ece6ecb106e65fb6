"""MAVLink 2 signing with a key file, shared by the flight controller side and the companion.

With a key, every outgoing packet is signed and an incoming one is accepted only with a good
signature; unsigned or badly signed packets are dropped and counted, except HEARTBEAT and
RADIO_STATUS (harmless, and sent unsigned by radios and some ground stations).

Checked as the MAVLink C library does, the signature first and then the timestamp:
pymavlink's own check (2.4.x) records a stream's timestamp before it checks the signature,
so one forged packet with a far-future timestamp would make every genuine packet of that
stream look replayed. `setup_signing` puts our check in its place on the protocol object.

Our own timestamp follows the wall clock (10 us since 2015-01-01, as the spec asks of a system
that knows the time): at least the clock's, one more for every packet sent, and at least the
newest accepted from a peer and the clock's reading when it was accepted (what pymavlink's
check sets through the getter), so a clock stepped back (NTP, a board without a real-time
clock) leaves a receive-only link's window for new streams where it was. pymavlink alone only
counts packets from the instant of set-up, so a peer that had kept our timestamps across its
restart (below) would refuse us for as long as our packets take to count past them.

Replay across a restart: pymavlink accepts a new stream (link id, system, component) whose
timestamp is at most a minute behind its own clock, so a packet captured before a restart
would pass again. `StreamTimestamps` keeps the last timestamp of each stream, and our own, in
a file (the spec asks for our own), saved on a thread of its own (`keep_saving`: off the
loop that signs and checks the packets, twice every `SAVE_PERIOD_S`) and once more on
`close`; on load each is advanced by that period (what may have been accepted or sent after
the last save), so no packet signed before the restart is accepted after it, and none of
ours is signed twice.

Keys: `write_new_key` makes one (32 random bytes, or the SHA-256 of a passphrase, as MAVProxy's
`signing setup PASSPHRASE` does, so a ground station given the passphrase puts the same key
on a flight controller) into a file only its owner may read.
`refusal(key, packet)` says why signing refused a packet: unsigned, a bad signature, or a
good one on a timestamp not newer than its stream's (a replay).
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import os
import secrets
import threading
import time
from functools import partial
from dataclasses import dataclass
from pathlib import Path

from m4.log_limit import RepeatFilter
from m4.mavlink.dialect import mavlink
from m4.mavlink.packing import SIGNATURE_BYTES, signature
from m4.toml_fields import ConfigError

log = logging.getLogger(__name__)
log.addFilter(RepeatFilter())          # a peer with the wrong key must not flood the log

KEY_BYTES = 32
UNSIGNED_ALLOWED_IDS = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_RADIO_STATUS})
_SIGNING_EPOCH_UNIX_S = 1420070400         # MAVLink signing timestamps count 10 us from 2015-01-01
_TICKS_PER_S = 100_000
NEW_STREAM_BEHIND_S = 60                   # a new stream may start this far behind our timestamp
SAVE_PERIOD_S = 1.0


def load_key(path: str | Path) -> bytes:
    """A 32-byte secret key from a file holding 64 hex digits (whitespace ignored) or 32 raw bytes."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise ConfigError(f"signing key {path}: cannot read ({e.strerror})") from None
    try:
        key = bytes.fromhex(raw.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        key = raw
    if len(key) != KEY_BYTES:
        raise ConfigError(f"signing key {path}: expected {KEY_BYTES} bytes (or {2 * KEY_BYTES} hex digits), "
                          f"got {len(key)} bytes")
    return key


def key_from_passphrase(passphrase: str) -> bytes:
    """The key a ground station derives from a passphrase (MAVProxy's `signing setup`: SHA-256)."""
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def write_new_key(path: str | Path, passphrase: str | None = None) -> bytes:
    """A new key (32 random bytes; with `passphrase`, its SHA-256) written to `path` as 64 hex
    digits, readable and writable by its owner only (0600). ConfigError if `path` exists or
    cannot be written: a key in use is never replaced by accident."""
    path = Path(path)
    key = secrets.token_bytes(KEY_BYTES) if passphrase is None else key_from_passphrase(passphrase)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as e:
        raise ConfigError(f"signing key {path}: cannot create ({e.strerror})") from None
    with os.fdopen(fd, "w") as f:
        f.write(key.hex() + "\n")
    return key


def _wall_timestamp() -> int:
    """Now, in signing timestamp units (10 us since 2015-01-01)."""
    return int((time.time() - _SIGNING_EPOCH_UNIX_S) * _TICKS_PER_S)


class _WallClockSigning(mavlink.MAVLinkSigning):
    """pymavlink's signing state whose own timestamp never falls behind the wall clock; with
    the key's SHA-256 state kept (`keyed`: a copy of it starts each signature, sent or checked,
    m4.mavlink.packing.signature)."""

    keyed = None

    @property
    def timestamp(self) -> int:
        return max(self._timestamp, _wall_timestamp())

    @timestamp.setter
    def timestamp(self, value: int) -> None:
        self._timestamp = value


def _allow_unsigned(_mav, msg_id: int) -> bool:
    return msg_id in UNSIGNED_ALLOWED_IDS


def check_signature(mav: mavlink.MAVLink, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """pymavlink's MAVLink.check_signature with the checks in the C library's order: a packet
    counts (and its timestamp is recorded) only when its signature is good and its timestamp
    is newer than the last of its stream (link id, system, component), or, for a new stream,
    at most NEW_STREAM_BEHIND_S behind our own timestamp."""
    s = mav.signing
    if not hmac.compare_digest(signature(s.keyed, memoryview(msgbuf)[:-SIGNATURE_BYTES]), msgbuf[-SIGNATURE_BYTES:]):
        log.info("signature mismatch: packet dropped")
        return False
    timestamp = int.from_bytes(msgbuf[-12:-6], "little")         # 48 bits
    stream = (msgbuf[-13], src_system, src_component)
    last = s.stream_timestamps.get(stream)
    fresh = timestamp > last if last is not None else timestamp >= s.timestamp - NEW_STREAM_BEHIND_S * _TICKS_PER_S
    if not fresh:
        log.info("signed packet with an old timestamp (a replay?): dropped")
        return False
    s.stream_timestamps[stream] = timestamp
    s.timestamp = max(s.timestamp, timestamp)     # the clock's reading kept with it (the getter adds it): it may step back
    return True


def refusal(key: bytes, packet: bytes) -> str:
    """Why signing with `key` refused `packet` (one whole frame): "unsigned", "bad signature", or
    "replayed" (its signature is good: its timestamp was not newer than its stream's)."""
    if len(packet) < 3 or packet[0] != mavlink.PROTOCOL_MARKER_V2 or not packet[2] & mavlink.MAVLINK_IFLAG_SIGNED:
        return "unsigned"
    good = hmac.compare_digest(signature(hashlib.sha256(key), packet[:-SIGNATURE_BYTES]),
                               bytes(packet[-SIGNATURE_BYTES:]))
    return "replayed" if good else "bad signature"


def setup_signing(mav: mavlink.MAVLink, key: bytes, link_id: int = 0) -> None:
    """Sign everything `mav` sends and drop what it receives unsigned (but the allow-list) or
    badly signed (check_signature)."""
    if len(key) != KEY_BYTES:
        raise ValueError(f"signing key must be {KEY_BYTES} bytes, got {len(key)}")
    s = mav.signing = _WallClockSigning()
    s.secret_key = key
    s.keyed = hashlib.sha256(key)
    s.sign_outgoing = True
    s.allow_unsigned_callback = _allow_unsigned
    s.link_id = link_id
    mav.check_signature = partial(check_signature, mav)


@dataclass(frozen=True)
class SigningCounters:
    signed_ok: int            # packets with a good signature
    bad_signature: int        # packets with a wrong signature (or a replayed timestamp)
    unsigned_allowed: int     # unsigned packets let through by the allow-list
    rejected: int             # packets dropped: unsigned or badly signed, not on the allow-list

    @classmethod
    def of(cls, mav: mavlink.MAVLink) -> SigningCounters:
        s = mav.signing
        return cls(signed_ok=s.goodsig_count, bad_signature=s.badsig_count,
                   unsigned_allowed=s.unsigned_count, rejected=s.reject_count)


class StreamTimestamps:
    """The last accepted signing timestamp of every stream the protocol objects `mavs` (the
    links of one process) have heard, and the newest they signed with, kept in `path`.
    ConfigError if it cannot be read or written."""

    def __init__(self, mavs: list[mavlink.MAVLink], path: str | Path):
        self.mavs = mavs
        self.path = Path(path)
        try:
            stored = json.loads(self.path.read_text()) if self.path.exists() else {}
            streams = {tuple(int(x) for x in k.split(",")): int(v) for k, v in stored.get("streams", {}).items()}
            own = int(stored.get("own", 0))
        except (OSError, ValueError, AttributeError) as e:
            raise ConfigError(f"signing timestamps {self.path}: cannot read ({e})") from None
        ahead = round(SAVE_PERIOD_S * _TICKS_PER_S)
        for mav in mavs:
            for stream, timestamp in streams.items():
                mav.signing.stream_timestamps[stream] = timestamp + ahead
            mav.signing.timestamp = max([mav.signing.timestamp, own + ahead, *mav.signing.stream_timestamps.values()])
        self._stop_saving = threading.Event()
        self._saver: threading.Thread | None = None
        self.save()

    def keep_saving(self) -> StreamTimestamps:
        """Save every SAVE_PERIOD_S / 2 on a thread of its own until close(), so the loop that
        signs and checks packets never waits on the file. A save that fails is logged (rate
        limited) and tried again."""
        self._saver = threading.Thread(target=self._save_periodically, name="signing-timestamps", daemon=True)
        self._saver.start()
        return self

    def _save_periodically(self) -> None:
        while not self._stop_saving.wait(SAVE_PERIOD_S / 2):
            try:
                self.save()
            except ConfigError as e:
                log.warning("%s; a restart may accept a replay of what came since the last save", e)

    def close(self) -> None:
        """Stop the saving thread, then save once more: the newest timestamps, at exit.
        ConfigError if that save fails."""
        self._stop_saving.set()
        if self._saver is not None:
            self._saver.join()
            self._saver = None
        self.save()

    def save(self) -> None:
        """Write the timestamps now, atomically. The dictionaries are copied first (one C call
        each), so the saving thread may read them while the loop's thread adds to them."""
        streams: dict[str, int] = {}
        for mav in self.mavs:
            for stream, timestamp in list(mav.signing.stream_timestamps.items()):
                key = ",".join(map(str, stream))
                streams[key] = max(streams.get(key, 0), timestamp)
        own = max(mav.signing.timestamp for mav in self.mavs)
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            tmp.write_text(json.dumps({"streams": streams, "own": own}))
            os.replace(tmp, self.path)
        except OSError as e:
            raise ConfigError(f"signing timestamps {self.path}: cannot write ({e.strerror})") from None
