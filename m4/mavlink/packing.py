"""pymavlink's packing of a MAVLink 2 frame, signed or not: the same bytes, in a third of the time.

Every message's `pack()` (generated) puts its fields into the payload with the message's own
struct and hands it to `MAVLink_message._pack`, which strips the payload's trailing zeros,
builds a header object and packs it, checks the frame through a CRC object and signs it
through `hashlib.new`: about 14 µs a signed frame, most of the SITL's cost of sending its
telemetry. `fast_pack` does the same with one struct for the header, the C CRC pymavlink
uses and `signature`, and leaves the message and the protocol object as `_pack` leaves
them (header, payload, CRC, buffer; sequence and signing timestamp). MAVLink 1 goes to
pymavlink's own. `m4.mavlink.dialect` installs it in place of pymavlink's.
"""

from __future__ import annotations

import hashlib
import struct

from m4.mavlink import m4_generated as mavlink

PYMAVLINK_PACK = mavlink.MAVLink_message._pack
_HEADER = struct.Struct("<BBBBBBBHB")          # magic, length, flags (2), seq, system, component, id
_CRC = struct.Struct("<H")
_SIGNATURE_HEAD = struct.Struct("<BQ")        # link id, then the timestamp's low 6 bytes (7 of the 9 packed)
SIGNATURE_BYTES = 6


def signature(keyed, signed_part) -> bytes:
    """The MAVLink 2 signature (the first 6 bytes of SHA-256(key + signed part)) of `signed_part`
    (bytes, or a memoryview of a packet: no copy) from `keyed`, the SHA-256 state after the key:
    a copy of it starts each signature, without OpenSSL looking the digest up again. The one
    implementation: the sender's (`fast_pack`) and the checks' (m4/mavlink/signing.py)."""
    digest = keyed.copy()
    digest.update(signed_part)
    return digest.digest()[:SIGNATURE_BYTES]


def fast_pack(self: mavlink.MAVLink_message, mav: mavlink.MAVLink, crc_extra: int, payload: bytes,
              force_mavlink1: bool = False) -> bytes:
    """MAVLink_message._pack, the same bytes and side effects."""
    if force_mavlink1 or mavlink.WIRE_PROTOCOL_VERSION != "2.0":
        return PYMAVLINK_PACK(self, mav, crc_extra, payload, force_mavlink1)
    payload = payload.rstrip(b"\0") or payload[:1]       # MAVLink 2 cuts trailing zeros, keeps one byte
    signing = mav.signing
    flags = mavlink.MAVLINK_IFLAG_SIGNED if signing.sign_outgoing else 0
    msg_id = self._header.msgId
    self._payload = payload
    self._header = mavlink.MAVLink_header(msg_id, flags, 0, len(payload), mav.seq, mav.srcSystem, mav.srcComponent)
    frame = _HEADER.pack(mavlink.PROTOCOL_MARKER_V2, len(payload), flags, 0, mav.seq, mav.srcSystem,
                         mav.srcComponent, msg_id & 0xFFFF, msg_id >> 16) + payload
    self._crc = mavlink.mcrf4xx(frame[1:] + bytes((crc_extra,)), 0xFFFF)
    frame += _CRC.pack(self._crc)
    if signing.sign_outgoing:
        timestamp = signing.timestamp
        frame += _SIGNATURE_HEAD.pack(signing.link_id, timestamp)[:7]
        keyed = getattr(signing, "keyed", None)       # kept by setup_signing; pymavlink's own signing has none
        frame += signature(hashlib.sha256(signing.secret_key) if keyed is None else keyed, frame)
        signing.timestamp = timestamp + 1
    self._msgbuf = bytearray(frame)
    return frame
