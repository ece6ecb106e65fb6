"""The live feed on Zenoh: keys m4/<vehicle>/<topic>, JSON payloads.

payloads: the schema, built from plain data (no Zenoh); settings: where the feed goes;
transport: Zenoh itself. The companion's publisher is `companion.feed_publisher`.
"""
