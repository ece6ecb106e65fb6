"""A second sender claiming a paired identity: where the paired one speaks from, and the reports."""

from __future__ import annotations

from m4.mavlink.second_sender import LIVE_S, REPORT_PERIOD_S, PairedPlace, SecondSender


class Clock:
    def __init__(self):
        self.now = 50.0

    def __call__(self) -> float:
        return self.now


def test_another_place_is_a_second_sender_while_the_paired_one_is_live_and_a_restart_after():
    clock = Clock()
    place = PairedPlace(clock)
    assert not place.other("companion") and not place.other("companion")
    clock.now += 0.9 * LIVE_S
    assert place.other("stranger") and place.place == "companion"
    clock.now += 1.1 * LIVE_S                       # the companion fell silent: restarted elsewhere
    assert not place.other("restarted companion") and place.place == "restarted companion"
    assert place.other("companion")


def test_reports_are_rate_limited_and_say_how_many_were_held_back():
    clock, lines, texts = Clock(), [], []
    report = SecondSender("the companion", (1, 191), "FC", lines.append, texts.append, clock)
    for _ in range(5):
        report("127.0.0.1:5555", "unsigned")
    clock.now += REPORT_PERIOD_S
    report("127.0.0.1:5555", "replayed", "captured before")
    assert report.count == 6
    assert texts == ["FC: second sender as 1/191 (unsigned)", "FC: second sender as 1/191 (replayed)"]
    assert all(len(t) <= 50 for t in texts)
    assert lines[1] == ("a second sender claims to be the companion 1/191, from 127.0.0.1:5555: replayed "
                        "(captured before); 4 more since the last report; 6 so far")
