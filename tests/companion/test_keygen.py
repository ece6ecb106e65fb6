"""`m4-companion keygen`: a signing key file for its owner only, from a passphrase a ground station
can give the flight controller; bad input is one line and exit code 2."""

from __future__ import annotations

import hashlib
import io
import stat

from companion.cli import main
from m4.mavlink.signing import load_key


def test_a_new_key_comes_with_its_passphrase_shown_once(capsys, tmp_path):
    path = tmp_path / "mavlink.key"
    assert main(["keygen", str(path)]) == 0
    passphrase = capsys.readouterr().out.strip()
    assert len(passphrase) >= 40                                # 256 random bits
    assert load_key(path) == hashlib.sha256(passphrase.encode()).digest()
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert passphrase not in path.read_text()


def test_a_passphrase_the_fc_already_has_gives_its_key(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr("sys.stdin", io.StringIO("correct horse battery staple\n"))
    path = tmp_path / "mavlink.key"
    assert main(["keygen", str(path), "--passphrase-stdin"]) == 0
    assert capsys.readouterr().out == ""                        # nothing secret printed
    assert load_key(path) == hashlib.sha256(b"correct horse battery staple").digest()


def test_an_existing_key_is_not_replaced(capsys, tmp_path):
    path = tmp_path / "mavlink.key"
    path.write_text("a" * 64)
    assert main(["keygen", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("m4-companion: error:") and "exists" in lines[0]
    assert path.read_text() == "a" * 64


def test_an_empty_passphrase_is_refused(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr("sys.stdin", io.StringIO("\n"))
    assert main(["keygen", str(tmp_path / "k"), "--passphrase-stdin"]) == 2
    assert "empty" in capsys.readouterr().err and not (tmp_path / "k").exists()
