"""The companion's live feed on Zenoh: keys m4/<vehicle>/<topic>, JSON payloads.

payloads: the schema, built from plain data (no Zenoh); settings: where the feed goes;
transport: Zenoh itself; publisher: the Feed the control loop calls.
"""

from companion.feed.payloads import FAULT_STATES, TOPICS, key_for
from companion.feed.publisher import Feed, open_feed
from companion.feed.settings import FeedSettings, parse_feed_settings
from companion.feed.transport import FeedError

__all__ = ["FAULT_STATES", "TOPICS", "Feed", "FeedError", "FeedSettings", "key_for",
           "open_feed", "parse_feed_settings"]
