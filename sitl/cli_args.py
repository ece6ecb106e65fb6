"""Argument types and the bad-input error shared by the `m4-sitl` subcommands (sitl/cli.py
and sitl/flight_cli.py)."""

from __future__ import annotations

import argparse

from m4.arguments import number
from sitl.links.emulation import DELAY_MAX_MS, LinkEmulation


class BadInput(Exception):
    """A command-line argument is wrong, or the server cannot start with it."""


class Parser(argparse.ArgumentParser):
    def error(self, message):              # one line, not the usage block
        raise BadInput(f"{self.prog}: {message}")


def link_delay_ms(text: str) -> float:
    value = number(text)
    if not 0.0 <= value <= DELAY_MAX_MS:
        raise argparse.ArgumentTypeError(f"must be within 0..{DELAY_MAX_MS:g} ms, got {text}")
    return value


def link_loss(text: str) -> float:
    value = number(text)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"must be a probability within 0..1 (1 excluded), got {text}")
    return value


def add_link_arguments(p: argparse.ArgumentParser, realtime: str) -> None:
    """--link-delay-ms and --link-loss; `realtime` says what they do with --realtime."""
    p.add_argument("--link-delay-ms", type=link_delay_ms, default=0.0, metavar="MS",
                   help=f"delay on the companion's MAVLink link each way, 0..{DELAY_MAX_MS:g} ms: in lockstep emulated in "
                        f"simulated time by the SITL (deterministic); {realtime}")
    p.add_argument("--link-loss", type=link_loss, default=0.0, metavar="P",
                   help="share of datagrams lost each way on that link, 0..1 (1 excluded), drawn from --seed in "
                        f"lockstep; {realtime}")


def link_of(args) -> LinkEmulation | None:
    """The link impairment asked for by --link-delay-ms and --link-loss (None: none)."""
    if not (args.link_delay_ms or args.link_loss):
        return None
    return LinkEmulation(delay_ms=args.link_delay_ms, loss=args.link_loss)
