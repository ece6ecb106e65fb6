"""`m4-companion run [--fc URL] [--config FILE] [--mission FILE] [--signing-key FILE]`: the companion in flight.

Reads the configuration (defaults without --config), builds the NMPC (compiling it on a
first start, cached) and opens the link before it says "ready" (in its log and, with
--ready-fd, as one line written to that descriptor, which it then closes: the signal a
supervisor such as `m4-sitl fly` waits for), having put its loop in the real-time class the
configuration asks for (companion/realtime.py), then runs until SIGINT or SIGTERM. It says
where its flight log goes and whether its feed is on; its last line says what stopped it and
how the flight ended (the flight controller's shutdown, a lost link, still flying). A bad
configuration, URL, key, feed setting, ready descriptor or a port in use prints one line on
stderr and exits with 2; a feed that cannot reach Zenoh does not stop it (it is said and
tried again in the background).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import logging
import os
import signal
import sys
from pathlib import Path

from m4.toml_fields import ConfigError

EXIT_BAD_INPUT = 2


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fc", metavar="URL", help="the flight controller: udpin:HOST:PORT, udpout:HOST:PORT, "
                                               "tcp:HOST:PORT, tcpin:HOST:PORT or /dev/NAME,BAUD "
                                               "(default: the configuration's [link] fc_url)")
    p.add_argument("--config", type=Path, metavar="FILE", help="the companion's TOML configuration")
    p.add_argument("--mission", type=Path, metavar="FILE",
                   help="a scenario file or a file with a [mission] table (default: the configuration's)")
    p.add_argument("--signing-key", type=Path, metavar="FILE",
                   help="the MAVLink signing key (m4-companion keygen; default: the configuration's [link] "
                        "signing_key_file), the one the flight controller has")
    p.add_argument("--ready-fd", type=int, metavar="FD",
                   help="an open file descriptor: once the NMPC is built and the link is open, write one line "
                        "to it and close it (for a supervisor, e.g. m4-sitl fly)")


def _check_ready_fd(fd: int | None) -> None:
    """Refuse a ready descriptor that is not open before the long build, not after it."""
    if fd is None:
        return
    try:
        os.fstat(fd)
    except OSError as e:
        raise ConfigError(f"--ready-fd {fd}: {e.strerror}") from None


def _say_ready(fd: int, text: str) -> None:
    try:
        with os.fdopen(fd, "w") as ready:
            ready.write(text + "\n")
    except OSError as e:             # the supervisor is gone: fly on, it was only a notice
        logging.getLogger("m4-companion").warning("could not write the ready line to --ready-fd %d: %s", fd,
                                                  e.strerror)


def _config(args: argparse.Namespace):
    from companion.config import load_config
    from companion.params import with_params_file
    from m4.mavlink.connect import check_url
    from m4.scenario import load_mission

    config = load_config(args.config)
    link = {}
    if args.fc is not None:
        link["fc_url"] = check_url(args.fc)
    if args.signing_key is not None:
        link.update(signing=True, signing_key_path=args.signing_key)
    config = dataclasses.replace(config, link=dataclasses.replace(config.link, **link))
    if args.mission is not None:
        config = dataclasses.replace(config, mission=load_mission(args.mission), mission_path=args.mission)
    return with_params_file(config)


def _say_outputs(config, flight_log) -> None:
    """Where the flight log goes and whether the feed is on: neither is a surprise later."""
    log = logging.getLogger("m4-companion")
    if flight_log.enabled:
        log.info("flight log: %s (a new file at each arming; [log] dir sets the folder)", flight_log.files[-1])
    elif not config.log.enabled:
        log.info("flight log off ([log] enabled = false)")
    if not config.feed.enabled:
        log.info("feed off: m4-companion watch and dashboard see nothing ([feed] enabled = true turns it on: "
                 "docs/dashboard.md)")


def _ms(value_ms: float | None, decimals: int) -> str:
    return "not measured" if value_ms is None else f"{value_ms:.{decimals}f} ms"


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="m4-companion: %(message)s", stream=sys.stderr)
    from companion.app import close_app, open_app
    from companion.core.codegen_cache import CodegenError
    from companion.realtime import use_cpu, use_realtime
    from m4.mavlink.link import LinkError

    try:
        _check_ready_fd(args.ready_fd)
        config = _config(args)
        use_cpu(config.cpu)         # before the feed's and the flight log's threads: they inherit it
        app = open_app(config)
    except (ConfigError, LinkError, CodegenError) as e:
        print(f"m4-companion: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    stopped_by = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda number, _: (stopped_by.append(signal.Signals(number).name), app.stop()))
    use_realtime(config.realtime_priority)       # once built: the compiler and the feed's threads stay normal
    ready = f"ready: {config.rate_hz:g} Hz on {config.link.fc_url}"
    logging.getLogger("m4-companion").info(ready)
    if args.ready_fd is not None:
        _say_ready(args.ready_fd, ready)
    _say_outputs(config, app.flight_log)
    gc.freeze()       # what was built to fly (NMPC, dialect, links) is never garbage: no collection walks it mid-flight
    try:
        app.run()
    finally:
        close_app(app)
        c = app.counters
        lead, timing = app.fc.delay.lead_s, app.timing
        logging.getLogger("m4-companion").info(
            "stopped%s after %d setpoints (%s); %d link losses; slowest solve %.1f ms; %d steps over the period; "
            "setpoint lead %s; telemetry read to setpoint sent %s on average, median %s, p99 %s; CPU %s per step",
            "".join(f" by {name}" for name in stopped_by[:1]), c.answered, app.end(), c.link_losses, c.solve_ms_max, timing.overruns, _ms(None if lead is None else 1e3 * lead, 0),
            _ms(timing.mean_answer_ms, 2), _ms(timing.answer_quantile_ms(0.5), 2), _ms(timing.answer_quantile_ms(0.99), 2),
            _ms(timing.cpu_ms_per_step, 2))
    return 0
