"""A datagram of MAVLink 2 frames read into pymavlink's message objects, a frame at a time.

pymavlink's parser (`MAVLink.parse_buffer`) walks a datagram through its byte-stream state
machine and decodes each frame generically: about 20 µs a frame, 0.15 ms for a telemetry
frame of seven messages. A datagram from a MAVLink 2 peer is whole frames back to back, so
this reader splits it by the frames' own lengths and decodes each with a plan made once per
message type, into the very objects pymavlink's decode builds (fields, buffers, CRC, header).

Only the plain case is read here: a parser holding no partial frame and no callbacks on it,
and every frame of the datagram MAVLink 2 of a known message with a good CRC, unsigned on a
link without a key or signed on a link with one. A signed frame is judged as pymavlink's
decode judges it (the link's `check_signature`, m4/mavlink/signing.py, then the unsigned
allow-list), with the same counters, and a refused one comes back as the same BAD_DATA.
Anything else (a frame cut short, garbage, MAVLink 1, an unsigned frame where a key asks for
signatures, a signed one without a key, an unknown message, a bad CRC) goes to pymavlink's
parser unchanged, the datagram whole, before any signature of it was checked, so garbage is
counted and signatures are judged exactly as before.
"""

from __future__ import annotations

import struct

from m4.mavlink.dialect import mavlink

_HEADER = struct.Struct("<cBBBBBBHB")       # pymavlink's MAVLink 2 header, magic included
_CRC = struct.Struct("<H")
_HEADER_LEN = mavlink.HEADER_LEN_V2
_CRC_LEN = 2
_MAGIC = mavlink.PROTOCOL_MARKER_V2
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_SIGNATURE_LEN = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
_SIGNED_TAIL = _CRC_LEN + _SIGNATURE_LEN
_SIGNATURE_REFUSED = "Invalid signature"      # pymavlink's BAD_DATA reason


class _Plan:
    """How pymavlink's decode turns one message type's payload into its message object: the
    arguments from the unpacked payload, and the attributes its constructor sets that no frame
    changes, read off one object it built (so they stay pymavlink's)."""

    def __init__(self, message_class):
        self.message_class = message_class
        self.crc_extra = bytes([message_class.crc_extra])
        self.unpacker = message_class.unpacker
        self.fieldnames = message_class.fieldnames
        lengths = message_class.lengths
        # (start in the unpacked tuple, count) of each argument, in the order of the arguments
        self.fields = [(sum(lengths[:order]), lengths[order]) for order in message_class.orders]
        self.has_arrays = sum(lengths) != len(lengths)
        self.has_text = "char" in message_class.fieldtypes
        # the arguments are the unpacked tuple itself: no arrays or text, wire order the arguments' order
        self.as_unpacked = not self.has_arrays and not self.has_text and \
            list(message_class.orders) == list(range(len(lengths)))
        self.constants = _constants(message_class)

    def arguments(self, frame: bytearray, start: int, end: int) -> tuple | list:
        """The arguments of the payload frame[start:end]."""
        size = self.unpacker.size
        if end - start >= size:
            t = self.unpacker.unpack_from(frame, start)
        else:                                               # MAVLink 2 cut the payload's trailing zeros
            t = self.unpacker.unpack_from(frame[start:end] + bytes(size - end + start))
        if self.as_unpacked:
            return t
        if not self.has_text:
            return [t[at] if count == 1 else list(t[at:at + count]) for at, count in self.fields]
        args = [t[at] if count == 1 or isinstance(t[at], bytes) else list(t[at:at + count])
                for at, count in self.fields]
        return [a.rstrip(b"\x00") if isinstance(a, bytes) else a for a in args]

    def message(self, frame: bytearray, crc_at: int, signed: bool = False):
        """What pymavlink's `MAVLink.decode` returns for this whole frame (its CRC at `crc_at`),
        marked signed (with its link id) when its signature was accepted."""
        _, length, incompat_flags, compat_flags, seq, system, component, id_low, id_high = _HEADER.unpack_from(frame)
        if self.constants is None:
            msg = self.message_class(*self.arguments(frame, _HEADER_LEN, crc_at))
            attributes = msg.__dict__
        else:
            attributes = self.constants.copy()
            attributes.update(zip(self.fieldnames, self.arguments(frame, _HEADER_LEN, crc_at)))
            msg = object.__new__(self.message_class)
            msg.__dict__ = attributes
        attributes["_msgbuf"] = frame
        attributes["_payload"] = frame[6:crc_at]              # sic: pymavlink's slice
        attributes["_crc"] = _CRC.unpack_from(frame, crc_at)[0]
        attributes["_header"] = mavlink.MAVLink_header(id_low | id_high << 16, incompat_flags, compat_flags, length,
                                                       seq, system, component)
        if signed:
            attributes["_signed"] = True
            attributes["_link_id"] = frame[-_SIGNATURE_LEN]
        return msg


def _constants(message_class) -> dict | None:
    """The attributes pymavlink's constructor of `message_class` sets whatever the arguments; None
    when it does more than keep its arguments (STATUSTEXT decodes its text)."""
    marks = [object() for _ in message_class.fieldnames]
    try:
        built = message_class(*marks)
    except (AttributeError, TypeError):
        return None
    kept = [vars(built).get(name) for name in message_class.fieldnames]
    if any(a is not b for a, b in zip(kept, marks)):
        return None
    return {k: v for k, v in vars(built).items() if k not in message_class.fieldnames}


_PLANS: dict[int, _Plan] = {}


def _plan(message_id: int) -> _Plan | None:
    plan = _PLANS.get(message_id)
    if plan is None and message_id in mavlink.mavlink_map:
        plan = _PLANS[message_id] = _Plan(mavlink.mavlink_map[message_id])
    return plan


def read_datagram(mav: mavlink.MAVLink, data: bytes) -> list:
    """The messages of one datagram, as `mav.parse_buffer(data) or []` gives them (rejected and
    garbled packets as BAD_DATA), with mav's counters moved the same way."""
    frames = _plain_frames(mav, data)
    if frames is None:
        return mav.parse_buffer(data) or []
    mav.total_bytes_received += len(data)
    mav.total_packets_received += len(frames)
    if mav.signing.secret_key is None:
        return [plan.message(bytearray(data[start:end]), end - start - _CRC_LEN) for start, end, plan in frames]
    return _decode_signed(mav, data, frames)


def _plain_frames(mav: mavlink.MAVLink, data: bytes) -> list[tuple[int, int, _Plan]] | None:
    """Each frame of `data`, (start, end, plan); None when any of it is not the plain case."""
    if mav.buf_len() != 0 or mav.callback is not None:
        return None
    flags = 0 if mav.signing.secret_key is None else _SIGNED       # the one flag every frame must carry
    tail = _CRC_LEN + (_SIGNATURE_LEN if flags else 0)
    frames, start, end = [], 0, len(data)
    while start < end:
        if end - start < _HEADER_LEN + tail or data[start] != _MAGIC or data[start + 2] != flags:
            return None                        # cut short, not MAVLink 2, unknown flags, signed or not as it may not be
        crc_at = start + _HEADER_LEN + data[start + 1]
        message_id = data[start + 7] | data[start + 8] << 8 | data[start + 9] << 16
        plan = _PLANS.get(message_id) or _plan(message_id)
        if crc_at + tail > end or plan is None or \
                _CRC.unpack_from(data, crc_at)[0] != _crc(data[start + 1:crc_at], plan):
            return None
        frames.append((start, crc_at + tail, plan))
        start = crc_at + tail
    return frames


def _crc(covered: bytes, plan: _Plan) -> int:
    """The frame's checksum: of the bytes after the magic up to the CRC, then the message's CRC_EXTRA."""
    return mavlink.mcrf4xx(plan.crc_extra, mavlink.mcrf4xx(covered, 0xFFFF))


def _decode_signed(mav: mavlink.MAVLink, data: bytes, frames: list[tuple[int, int, _Plan]]) -> list:
    """pymavlink's decode of signed frames on a link with a key: each signature checked, then the
    unsigned allow-list for a frame it refuses, the counters moved; BAD_DATA for a refused one."""
    check, out, good = mav.check_signature, [], 0
    for start, end, plan in frames:
        frame = bytearray(data[start:end])
        if check(frame, frame[5], frame[6]):
            msg = plan.message(frame, end - start - _SIGNED_TAIL, signed=True)
            good += 1
        else:
            msg = _refused(mav, frame, plan)
        out.append(msg)
    mav.signing.sig_count += len(frames)
    mav.signing.goodsig_count += good
    return out


def _refused(mav: mavlink.MAVLink, frame: bytearray, plan: _Plan):
    """A frame whose signature was refused: the message, unsigned, when the allow-list lets it
    pass; else BAD_DATA."""
    signing = mav.signing
    signing.badsig_count += 1
    allowed = signing.allow_unsigned_callback is not None and signing.allow_unsigned_callback(mav, plan.message_class.id)
    if allowed:
        signing.unsigned_count += 1
        return plan.message(frame, len(frame) - _SIGNED_TAIL)
    if signing.allow_unsigned_callback is not None:
        signing.reject_count += 1
    mav.total_receive_errors += 1
    return mavlink.MAVLink_bad_data(frame, _SIGNATURE_REFUSED)
