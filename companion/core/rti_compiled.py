"""The real-time iteration's feedback as ONE compiled call: moved, DAQP and plan in C.

`RtiFeedback`'s Python route makes three calls between the state and the plan: the compiled
`moved` function, DAQP's Python binding (`daqp.Model.update` and `solve`: about half of the
feedback's time) and the compiled `plan` function. Here the C of both functions (CasADi's
code generator), a small C source of ours (rti_feedback.c: a DAQP workspace and the
feedback's three steps) and DAQP's C library are compiled into one library, cached as
companion.core.codegen_cache caches every compiled function, and called through ctypes on
the functions' numpy buffers, holding the GIL: one call at the preparation (`load`: the
Hessian and the rows factorised into the workspace, as daqp.Model.update does), one at the
feedback. The QP is the same, solved by the same active-set method from the same active
set. DAQP's C library is the one CasADi's wheel ships (its headers and libdaqpstat.a), older
than the daqp wheel's: its solutions are the binding's to rounding while no soft row binds,
and within 0.03 N along benchmarks.rti's flight when one does (they weigh soft rows
differently: rti_feedback.c).

When the library cannot be built or loaded (no DAQP headers or library in CasADi's wheel,
rti_feedback.c missing, the compiler fails on it, the loader refuses it), CasADi is not a
version rti_feedback.c was checked on (CHECKED_CASADI) or `[nmpc] codegen = false`, the
Python route flies, and a log line says so once.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import weakref
from pathlib import Path

import casadi as ca
import numpy as np

from companion.core.casadi_call import BufferedFunction
from companion.core.codegen_cache import CodegenError, compiled_library

SOURCE = Path(__file__).with_name("rti_feedback.c")
INVALID_INPUT = -100            # rti_feedback.c's M4_RTI_INVALID_INPUT
# The CasADi versions whose DAQP rti_feedback.c was checked on (the x86_64 and aarch64 wheels):
# it reaches into DAQP's internals (the workspace's constraint marks, update_ldp's marking of
# equalities, reset_daqp_workspace and activate_constraints, a build without SOFT_WEIGHTS),
# which another version may change under a library that still builds.
CHECKED_CASADI = frozenset({"3.8.2"})
# DAQP's symbols stay inside our library: another DAQP in the process (the daqp wheel's) keeps its own.
_HIDE_ARCHIVES = "-Wl,--exclude-libs,ALL"

_log = logging.getLogger(__name__)


def daqp_c_library() -> tuple[Path, Path] | None:
    """(the folder holding daqp/api.h, libdaqpstat.a) as CasADi's wheel ships them; None when it does not."""
    root = Path(ca.__file__).parent
    include, archive = root / "include", root / "libdaqpstat.a"
    return (include, archive) if (include / "daqp" / "api.h").is_file() and archive.is_file() else None


def feedback_library(moved: ca.Function, plan: ca.Function, codegen: bool) -> Path | None:
    """The compiled library of the one-call feedback over `moved` and `plan`
    (companion.core.rti.feedback_functions); None (said once) when it is not to be had."""
    if not codegen:
        _say_once("the RTI feedback calls DAQP from Python: [nmpc] codegen = false")
        return None
    if ca.__version__ not in CHECKED_CASADI:
        _say_once(f"the RTI feedback calls DAQP from Python: rti_feedback.c was checked on the DAQP of CasADi "
                  f"{', '.join(sorted(CHECKED_CASADI))}, not of CasADi {ca.__version__}")
        return None
    daqp = daqp_c_library()
    if daqp is None:
        _say_once(f"the RTI feedback calls DAQP from Python: CasADi's wheel has no DAQP C headers and "
                  f"libdaqpstat.a under {Path(ca.__file__).parent}")
        return None
    include, archive = daqp
    try:
        library = compiled_library(f"m4_rti_feedback_{moved.name()}", [moved, plan], (SOURCE,),
                                   (f"-I{include}", f"-DM4_RTI_MOVED={moved.name()}", f"-DM4_RTI_PLAN={plan.name()}",
                                    str(archive), _HIDE_ARCHIVES))
        ctypes.PyDLL(str(library))                  # one that does not load is no route either
    except (CodegenError, OSError) as e:            # OSError: our C source missing, the library not loading
        _say_once(f"the RTI feedback calls DAQP from Python: {e}")
        return None
    return library


@functools.cache
def _say_once(message: str) -> None:
    _log.warning(message)


_DOUBLES = ctypes.POINTER(ctypes.c_double)
_POINTERS = ctypes.POINTER(ctypes.c_void_p)


class CompiledFeedback:
    """The feedback in `library` (feedback_library) on the buffers of `moved` and `plan`
    (BufferedFunctions of the library's two functions) for QPs of `variables` unknowns and the
    constraint kinds `sense` (simple bounds first), at most `iter_limit` DAQP iterations."""

    def __init__(self, library: Path, moved: BufferedFunction, plan: BufferedFunction, variables: int,
                 sense: np.ndarray, iter_limit: int):
        # PyDLL: the calls keep the GIL (27 us); CDLL's give it up, and another thread taking it
        # mid-answer held the answer up to a switch interval (5 ms).
        lib = ctypes.PyDLL(str(library))
        lib.m4_rti_new.restype = ctypes.c_void_p
        lib.m4_rti_new.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, _DOUBLES, _DOUBLES,
                                   ctypes.POINTER(ctypes.c_int), _DOUBLES, _POINTERS, _POINTERS, _POINTERS, _POINTERS]
        lib.m4_rti_load.argtypes = [ctypes.c_void_p, ctypes.c_int]
        lib.m4_rti_feedback.argtypes = [ctypes.c_void_p]
        lib.m4_rti_free.argtypes = [ctypes.c_void_p]
        lib.m4_rti_free.restype = None
        self._hess, self._rows = np.zeros((variables, variables)), np.zeros((sense.size - variables, variables))
        self._sense = np.ascontiguousarray(sense, dtype=np.intc)
        self._lam = np.zeros(sense.size)
        self._keep = (moved, plan)                 # their buffers are the library's
        pointers = [_pointers(group) for fn in (moved, plan) for group in fn.buffers()]
        handle = lib.m4_rti_new(variables, sense.size, iter_limit, *map(_doubles, (self._hess, self._rows)),
                                self._sense.ctypes.data_as(ctypes.POINTER(ctypes.c_int)), _doubles(self._lam),
                                *pointers)
        if not handle:
            raise MemoryError("CompiledFeedback: no memory for the DAQP workspace")
        weakref.finalize(self, lib.m4_rti_free, handle)
        self._load = functools.partial(lib.m4_rti_load, handle)
        self._feedback = functools.partial(lib.m4_rti_feedback, handle)

    def load(self, hess: np.ndarray, rows: np.ndarray, warm: bool) -> None:
        """The Hessian (n, n) and the constraint rows (m, n) of the next feedbacks; warm: start
        from the last solve's active set (else from none)."""
        for name, value, buffer in (("hess", hess, self._hess), ("rows", rows, self._rows)):
            if np.shape(value) != buffer.shape:
                raise ValueError(f"CompiledFeedback: {name} must have shape {buffer.shape}, got {np.shape(value)}")
            buffer[:] = value
        self._load(int(warm))

    def feedback(self) -> int:
        """moved, DAQP and plan (when DAQP's exitflag is > 0) on the buffers: INVALID_INPUT, the
        last load's negative flag, DAQP's exitflag, or rti_feedback.c's M4_RTI_PLAN_FAILED (< 0)."""
        return self._feedback()

    @property
    def duals(self) -> np.ndarray:
        """The last solve's duals (a buffer the next solve overwrites)."""
        return self._lam


def _doubles(array: np.ndarray):
    return array.ctypes.data_as(_DOUBLES)


def _pointers(buffers: list[np.ndarray]):
    return (ctypes.c_void_p * len(buffers))(*(b.ctypes.data for b in buffers))
