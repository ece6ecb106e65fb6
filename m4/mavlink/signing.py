"""MAVLink 2 signing with a key file, shared by the flight controller side and the companion.

With a key, every outgoing packet is signed and an incoming one is accepted only with a good
signature; unsigned or badly signed packets are dropped and counted, except HEARTBEAT and
RADIO_STATUS (harmless, and sent unsigned by radios and some ground stations).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from m4.mavlink.dialect import mavlink
from m4.toml_fields import ConfigError

KEY_BYTES = 32
UNSIGNED_ALLOWED_IDS = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_RADIO_STATUS})
_SIGNING_EPOCH_UNIX_S = 1420070400         # MAVLink signing timestamps count 10 us from 2015-01-01


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


def _allow_unsigned(_mav, msg_id: int) -> bool:
    return msg_id in UNSIGNED_ALLOWED_IDS


def setup_signing(mav: mavlink.MAVLink, key: bytes, link_id: int = 0) -> None:
    """Sign everything `mav` sends and drop what it receives unsigned (but the allow-list)."""
    if len(key) != KEY_BYTES:
        raise ValueError(f"signing key must be {KEY_BYTES} bytes, got {len(key)}")
    s = mav.signing
    s.secret_key = key
    s.sign_outgoing = True
    s.allow_unsigned_callback = _allow_unsigned
    s.link_id = link_id
    s.timestamp = max(s.timestamp, int((time.time() - _SIGNING_EPOCH_UNIX_S) * 100_000))


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
