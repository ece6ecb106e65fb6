"""`m4-companion keygen FILE [--passphrase-stdin]`: a MAVLink 2 signing key for the companion and
its flight controller (docs/authority.md).

The key is the SHA-256 of a passphrase, as MAVProxy's `signing setup PASSPHRASE` makes it, so a
ground station given the passphrase puts the same key on the flight controller. Without
--passphrase-stdin the passphrase is drawn at random (256 bits) and printed once on stdout,
never stored; with it, the passphrase is read from stdin (one the flight controller already
has). FILE gets the key as 64 hex digits, readable by its owner only (0600); an existing file
is never replaced. A bad FILE or an empty passphrase prints one line on stderr and exits with 2.
"""

from __future__ import annotations

import argparse
import secrets
import sys
from pathlib import Path

from m4.toml_fields import ConfigError

EXIT_BAD_INPUT = 2
PASSPHRASE_BYTES = 32


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", type=Path, metavar="FILE",
                   help="the key file to create (it must not exist), e.g. /etc/m4/mavlink.key")
    p.add_argument("--passphrase-stdin", action="store_true",
                   help="take the passphrase from stdin (one the flight controller already has) instead of a random one")


def run(args: argparse.Namespace) -> int:
    from m4.mavlink.signing import write_new_key

    given = args.passphrase_stdin
    passphrase = sys.stdin.readline().rstrip("\r\n") if given else secrets.token_urlsafe(PASSPHRASE_BYTES)
    try:
        if not passphrase:
            raise ConfigError("the passphrase on stdin is empty")
        write_new_key(args.file, passphrase)
    except ConfigError as e:
        print(f"m4-companion: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"m4-companion: wrote the signing key {args.file} (owner only, 0600)", file=sys.stderr)
    if not given:
        print("m4-companion: its passphrase, shown once and stored nowhere; the flight controller takes it from a "
              "ground station over USB (MAVProxy: signing setup PASSPHRASE; docs/authority.md):", file=sys.stderr)
        print(passphrase)
    return 0
