"""CasADi functions compiled to C once and cached on disk, keyed by a hash of the code.

The first use of a problem generates C, compiles it with the system C compiler (a few
seconds) and stores the shared library under the cache directory; every later start loads
it at once. The key is a hash of the generated source, the compiler command and CasADi's
version, so a change of model, horizon or step makes a new library and never reuses a stale
one. Writes are atomic (compile to a temporary name, then rename), so two processes
starting together cannot load a half-written file. `compiled_library` builds, the same way,
one library of several generated functions with C sources of ours and compiler flags (the
RTI's one-call feedback, with DAQP's library); its key hashes them too.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca

from m4.bytecode_cache import CACHE_ENV, cache_dir   # one cache folder for the project's compiled code

COMPILER_FLAGS = ("-O2", "-fPIC", "-shared")


class CodegenError(RuntimeError):
    """The C compiler is missing or failed."""


def _compiler() -> str:
    cc = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not cc:
        raise CodegenError("no C compiler found: install gcc, or set [nmpc] codegen = false (NmpcConfig(codegen=False))")
    return cc


def compiled(fn: ca.Function) -> ca.Function:
    """The same function as `fn`, loaded from a cached compiled library (built if missing)."""
    return ca.external(fn.name(), str(compiled_library(fn.name(), [fn])))


def compiled_library(name: str, fns: list[ca.Function], sources: tuple[Path, ...] = (),
                     flags: tuple[str, ...] = ()) -> Path:
    """The cached shared library (built if missing) of the C CasADi generates for `fns`, with the
    C files `sources` of ours and the compiler's `flags` (include folders, macros, libraries to
    link: after the sources). Its key hashes all of them too."""
    cc = _compiler()
    with tempfile.TemporaryDirectory(prefix="m4-codegen-") as tmp:
        src_name = f"{name}.c"
        gen = ca.CodeGenerator(src_name, {"with_header": False})
        for fn in fns:
            gen.add(fn)
        gen.generate(tmp + os.sep)
        paths = [Path(tmp, src_name), *sources]
        code = b"".join(path.read_bytes() for path in paths)
        key = hashlib.sha256(code + " ".join((cc, *COMPILER_FLAGS, *flags, ca.__version__)).encode()).hexdigest()[:16]
        lib = cache_dir() / f"{name}_{key}.so"
        if not lib.exists():
            try:
                lib.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise CodegenError(f"cannot create the cache directory {lib.parent} ({e.strerror}); "
                                   f"set {CACHE_ENV} to a writable one") from None
            partial = lib.with_suffix(f".{os.getpid()}.tmp")
            try:
                result = subprocess.run([cc, *COMPILER_FLAGS, "-o", str(partial), *map(str, paths), *flags, "-lm"],
                                        capture_output=True, text=True, check=False)
            except OSError as e:
                raise CodegenError(f"cannot run the C compiler {cc} ({e.strerror}): install gcc, or set "
                                   f"[nmpc] codegen = false") from None
            if result.returncode != 0:
                partial.unlink(missing_ok=True)
                raise CodegenError(f"compiling {name} failed: {result.stderr.strip()[:2000]}")
            os.replace(partial, lib)
    return lib
