"""The UDP impairment proxy (sitl/links/netem_proxy.py): delay, loss, duplicates and reordering both ways,
on real loopback sockets."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest

from sitl.links.netem_proxy import Impairment, Netem, NetemError, loopback_address


def _socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(1.0)
    return s


class _Pair:
    """A client writing to the proxy and a server behind it that echoes what it gets."""

    def __init__(self, impairment: Impairment, seed: int = 1, duration_s: float = 30.0):
        self.client, self.server = _socket(), _socket()
        self.netem = Netem(("127.0.0.1", 0), self.server.getsockname(), impairment, seed, duration_s).start()
        self.proxy = ("127.0.0.1", self.netem.listen_port)

    def received(self, sock: socket.socket, timeout_s: float = 0.5) -> list[bytes]:
        out = []
        sock.settimeout(timeout_s)
        while True:
            try:
                out.append(sock.recvfrom(65535)[0])
            except TimeoutError:
                return out

    def close(self):
        self.netem.close()
        self.client.close()
        self.server.close()


@pytest.fixture
def pair(request):
    p = _Pair(request.param)
    yield p
    p.close()


@pytest.mark.parametrize("pair", [Impairment(delay_ms=40.0)], indirect=True)
def test_each_direction_is_delayed(pair):
    t0 = time.monotonic()
    pair.client.sendto(b"ping", pair.proxy)
    data, proxy_side = pair.server.recvfrom(100)
    forward_s = time.monotonic() - t0
    pair.server.sendto(b"pong", proxy_side)
    assert pair.client.recvfrom(100)[0] == b"pong"
    round_trip_s = time.monotonic() - t0
    assert data == b"ping"
    assert 0.040 <= forward_s < 0.2
    assert 0.080 <= round_trip_s < 0.4


@pytest.mark.parametrize("pair", [Impairment(loss=0.3)], indirect=True)
def test_loss_drops_about_the_asked_fraction_and_counts_it(pair):
    got = []
    for chunk in range(10):                    # read as we go: 500 datagrams overflow a socket's buffer
        for i in range(50):
            pair.client.sendto((50 * chunk + i).to_bytes(2, "big"), pair.proxy)
        got += pair.received(pair.server, timeout_s=0.05)
    c = pair.netem.counters.forward
    assert c.received == 500
    assert c.lost + len(got) == 500
    assert 0.22 < c.lost / 500 < 0.38


@pytest.mark.parametrize("pair", [Impairment(duplicate=1.0)], indirect=True)
def test_duplicate_sends_each_datagram_twice(pair):
    for i in range(10):
        pair.client.sendto(bytes([i]), pair.proxy)
    got = pair.received(pair.server)
    assert sorted(got) == sorted([bytes([i]) for i in range(10)] * 2)


@pytest.mark.parametrize("pair", [Impairment(reorder=0.3, reorder_ms=30.0)], indirect=True)
def test_reorder_lets_later_datagrams_overtake(pair):
    for i in range(50):
        pair.client.sendto(bytes([i]), pair.proxy)
        time.sleep(0.002)
    got = [b[0] for b in pair.received(pair.server)]
    assert sorted(got) == list(range(50))
    assert got != sorted(got)
    assert pair.netem.counters.forward.reordered > 0


def test_it_stops_by_itself_after_its_duration():
    p = _Pair(Impairment(), duration_s=0.2)
    p.netem._thread.join(timeout=2.0)
    assert not p.netem._thread.is_alive()
    p.close()


@pytest.mark.parametrize("text", ["10.0.0.1:5000", "example.com:5000", "127.0.0.1", "127.0.0.1:99999"])
def test_only_loopback_addresses_are_accepted(text):
    with pytest.raises(NetemError, match="loopback only"):
        loopback_address(text)


def test_bad_impairment_is_refused():
    with pytest.raises(NetemError, match="loss must be within 0..1"):
        Impairment(loss=1.5)


def test_command_line_refuses_a_remote_address_in_one_line():
    r = subprocess.run([sys.executable, "-m", "sitl.links.netem_proxy", "--listen", "127.0.0.1:0", "--to", "8.8.8.8:53"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert r.stderr.strip() == "netem: error: bad address '8.8.8.8:53': expected 127.x.x.x:PORT (loopback only)"
