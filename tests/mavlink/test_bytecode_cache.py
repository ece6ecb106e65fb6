"""The dialect's bytecode cached under the cache folder, where Python may not cache it itself."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from m4.bytecode_cache import BYTECODE_DIR, CACHE_ENV, load_module

ROOT = Path(__file__).resolve().parents[2]
# Imports the dialect with compile() refusing it: it passes only if its code came from the cache.
_WITHOUT_COMPILING = ("import builtins\n"
                      "real = builtins.compile\n"
                      "def refuse(source, filename, *args, **kwargs):\n"
                      "    assert not str(filename).endswith('m4_generated.py'), 'compiled the dialect again'\n"
                      "    return real(source, filename, *args, **kwargs)\n"
                      "builtins.compile = refuse\n"
                      "import m4.mavlink\n")


def _python(code: str, cache: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, CACHE_ENV: str(cache), "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True, timeout=120,
                          check=False)


def test_a_second_process_loads_the_dialect_without_compiling_it(tmp_path):
    assert _python("import m4.mavlink", tmp_path).returncode == 0
    assert [p.name.split("-")[0] for p in (tmp_path / BYTECODE_DIR).iterdir()] == ["m4.mavlink.m4_generated"]
    second = _python(_WITHOUT_COMPILING, tmp_path)
    assert second.returncode == 0, second.stderr


def test_without_a_writable_cache_the_dialect_is_compiled_as_before(tmp_path):
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    done = _python("import m4.mavlink; print(m4.mavlink.mavlink.MAVLINK_MSG_ID_M4_SETPOINT)", blocked / "cache")
    assert done.returncode == 0 and done.stdout.strip().isdigit() and not done.stderr


@pytest.fixture
def package(tmp_path, monkeypatch):
    """An importable package `cachedpkg` in tmp_path, forgotten afterwards."""
    (tmp_path / "cachedpkg").mkdir()
    (tmp_path / "cachedpkg" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    yield tmp_path / "cachedpkg"
    for name in [n for n in sys.modules if n.startswith("cachedpkg")]:
        del sys.modules[name]


def test_an_edited_source_is_compiled_again(package):
    source = package / "gen.py"
    for value in (1, 2):
        source.write_text(f"VALUE = {value}\n")
        sys.modules.pop("cachedpkg.gen", None)
        import cachedpkg  # noqa: F401 - the parent package, as the dialect's is
        assert load_module("cachedpkg.gen", source).VALUE == value
    assert len(list((package.parent / "cache" / BYTECODE_DIR).iterdir())) == 2
