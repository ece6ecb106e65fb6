"""A large module's bytecode, cached under the project's cache folder where Python may not cache it.

Python keeps a module's compiled bytecode in `__pycache__` beside its source, unless it may not
(`PYTHONDONTWRITEBYTECODE`, as on the shared development machine and in CI, or a read-only
install): then every process compiles the module again. For the 35 000-line generated dialect
(m4/mavlink/m4_generated.py) that is about half a second of CPU at every start of the SITL or
the companion, so twice a flight. `load_module(name, path)` imports such a module with its code
cached under `cache_dir()` ($M4_CACHE_DIR, else $XDG_CACHE_HOME/m4-fault-recovery, else
~/.cache/m4-fault-recovery: where the NMPC keeps its compiled code), keyed by a hash of the
source and of the interpreter's bytecode version, so an edited source or another Python never
runs stale code. A cache folder that cannot be written is passed over: the module is compiled
as before. Writes are atomic (a temporary name, then a rename): processes starting together
never read half a file.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import marshal
import os
import sys
import tempfile
from pathlib import Path
from types import CodeType, ModuleType

CACHE_ENV = "M4_CACHE_DIR"
BYTECODE_DIR = "bytecode"


def cache_dir() -> Path:
    """$M4_CACHE_DIR, else $XDG_CACHE_HOME/m4-fault-recovery, else ~/.cache/m4-fault-recovery."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "m4-fault-recovery"


class _CachedLoader(importlib.machinery.SourceFileLoader):
    """A source file's loader whose code comes from the cache folder when it is there."""

    def get_code(self, fullname: str) -> CodeType:
        source = self.get_data(self.path)
        key = hashlib.sha256(importlib.util.MAGIC_NUMBER + source).hexdigest()[:16]
        cached = cache_dir() / BYTECODE_DIR / f"{fullname}-{key}.marshal"
        try:
            return marshal.loads(cached.read_bytes())
        except (OSError, EOFError, ValueError, TypeError):
            pass
        code = self.source_to_code(source, self.path)
        _write_atomically(cached, marshal.dumps(code))
        return code


def _write_atomically(path: Path, data: bytes) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:
        pass                     # no cache: the next start compiles again


def load_module(name: str, path: Path) -> ModuleType:
    """Import module `name` (a package's submodule, its package imported) from the source
    file `path`, its bytecode cached; the module already imported if it is."""
    if name in sys.modules:
        return sys.modules[name]
    loader = _CachedLoader(name, str(path))
    module = importlib.util.module_from_spec(importlib.util.spec_from_file_location(name, path, loader=loader))
    sys.modules[name] = module
    try:
        loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    parent, _, child = name.rpartition(".")
    setattr(sys.modules[parent], child, module)
    return module
