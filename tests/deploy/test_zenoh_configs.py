import json
from pathlib import Path

import zenoh

from m4.feed.settings import FeedSettings
from companion.watch import DEFAULT_CONNECT

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def load(name: str) -> zenoh.Config:
    return zenoh.Config.from_file(str(DEPLOY / name))     # Zenoh's own parser: typos are errors


def get(cfg: zenoh.Config, key: str):
    return json.loads(cfg.get_json(key))


def address(endpoint: str) -> str:
    """tcp/127.0.0.1:7447#iface=lo -> tcp/127.0.0.1:7447"""
    return endpoint.split("#", 1)[0].split("?", 1)[0]


def test_companion_session_is_a_peer_that_connects_to_the_router_and_opens_nothing():
    router, companion = load("zenoh-router.json5"), load("zenoh-companion.json5")
    assert get(companion, "mode") == "peer"
    assert get(companion, "listen/endpoints") == []
    assert get(companion, "scouting/multicast/enabled") is False
    assert get(companion, "scouting/gossip/enabled") is False
    router_listens = {address(e) for e in get(router, "listen/endpoints")}
    assert set(get(companion, "connect/endpoints")) <= router_listens
    FeedSettings(zenoh_config=DEPLOY / "zenoh-companion.json5").validate()


def test_watch_on_the_robot_reaches_the_router_by_default():
    router_listens = {address(e) for e in get(load("zenoh-router.json5"), "listen/endpoints")}
    assert DEFAULT_CONNECT in router_listens


def test_router_answers_scouts_but_connects_to_nobody_it_discovers():
    router = load("zenoh-router.json5")
    assert get(router, "mode") == "router"
    assert get(router, "scouting/multicast/listen") is True
    assert get(router, "scouting/multicast/autoconnect") == {"router": []}
    assert get(router, "scouting/gossip/enabled") is False
    assert get(router, "connect/endpoints") == []


def test_every_router_listener_is_bound_to_an_interface():
    for endpoint in get(load("zenoh-router.json5"), "listen/endpoints"):
        assert "#iface=" in endpoint, endpoint
