"""`m4-companion dashboard`: the live feed in a web browser, or a recorded flight replayed.

events: the feed's samples as the page's events (the posture computed from the airframe),
live fan-out and paced replay of a feed.jsonl; server: the HTTP server (the page, the
airframe, the events as Server-Sent Events); command: the command line; static/: the page
itself (HTML, CSS, JS of our own drawing on canvas, nothing fetched from elsewhere).
"""
