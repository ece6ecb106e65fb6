"""Calling a CasADi Function from numpy the cheap way: on preallocated buffers.

`fn(numpy arrays)` converts every argument to a DM and every result back, about 0.1 ms per
call on top of the evaluation itself (measured: a 6-output model step of 57 us took 170 us
called directly, 60 us on buffers). `BufferedFunction` binds numpy buffers to the function's
inputs and outputs once; a call copies the arguments in, evaluates and copies the results
out. The values are the function's own: the same evaluation, only the conversion is gone.
Inputs that change more slowly than the calls (what a preparation fixed for the next calls)
can be set apart as parameters: written once by `set_parameters`, kept between calls.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


class BufferedFunction:
    """`fn` evaluated on numpy buffers. Call with one array (or float) per input, each holding
    that input's entries in column-major order; returns one fresh array per output, shaped
    (rows, columns) like np.asarray of the DM it would return, sparse outputs made dense.
    An evaluation that reports failure gives NaN everywhere (like a diverged model).
    With `parameters` = k, the last k inputs are not passed at the calls: `set_parameters`
    writes them by name (zero until then), and every call after reads them. `shared` gives a
    parameter (by its name) the buffer of another BufferedFunction's parameter (`buffer`: one
    copy of a big parameter in memory for two functions, written by either) or result
    (`result`: what one function computes, the other reads without a copy)."""

    def __init__(self, fn: ca.Function, parameters: int = 0, shared: dict[str, np.ndarray] | None = None):
        if not all(fn.sparsity_in(i).is_dense() for i in range(fn.n_in())):
            raise ValueError(f"BufferedFunction: every input of {fn.name()} must be dense")
        if not 0 <= parameters <= fn.n_in():
            raise ValueError(f"BufferedFunction: {fn.name()} has {fn.n_in()} inputs, not {parameters} parameters")
        self._fn = fn                                  # the buffers below refer to it
        self._args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self._inputs = self._args[:fn.n_in() - parameters]
        self._parameters = {fn.name_in(i): i for i in range(fn.n_in() - parameters, fn.n_in())}
        for name, arr in (shared or {}).items():
            i = self._parameter(name)
            if arr.shape != self._args[i].shape or arr.dtype != np.float64:
                raise ValueError(f"BufferedFunction: parameter {name} of {fn.name()} takes {fn.nnz_in(i)} floats, "
                                 f"not a buffer of shape {arr.shape} and type {arr.dtype}")
            self._args[i] = arr
        self._results = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._shapes = [fn.size_out(i) for i in range(fn.n_out())]
        self._scatter = [_dense_positions(fn.sparsity_out(i)) for i in range(fn.n_out())]
        self._buffer, self._evaluate = fn.buffer()
        for i, arr in enumerate(self._args):
            self._buffer.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self._results):
            self._buffer.set_res(i, memoryview(arr))

    def __call__(self, *args) -> tuple[np.ndarray, ...]:
        return tuple(self._dense(i, nonzeros) for i, nonzeros in enumerate(self.evaluate(*args)))

    def evaluate(self, *args) -> list[np.ndarray]:
        """Each output's structural nonzeros in column-major order: the buffers themselves,
        overwritten by the next call."""
        self.set_inputs(*args)
        self._evaluate()
        if self._buffer.ret() != 0:
            for arr in self._results:
                arr.fill(np.nan)
        return self._results

    def set_inputs(self, *args) -> None:
        """The inputs of the next evaluation, as for a call, into their buffers."""
        try:
            for buffer, value in zip(self._inputs, args, strict=True):
                _write(buffer, value)
        except ValueError:
            self._check_sizes(args)                # naming the input; nothing spent on a call that fits
            raise

    def buffers(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """(every input's buffer, every output's), in the function's order: for compiled code
        that evaluates the function itself on them."""
        return self._args, self._results

    def buffer(self, name: str) -> np.ndarray:
        """The buffer of the parameter `name` (its entries in column-major order)."""
        return self._args[self._parameter(name)]

    def result(self, name: str) -> np.ndarray:
        """The buffer of the output `name` (its structural nonzeros), overwritten by every call."""
        return self._results[self._fn.index_out(name)]

    def set_parameters(self, **values) -> None:
        """Parameters' values by name (an array or float each, as for a call), for every call from now on.
        A value of another size than its parameter's raises ValueError (a call's input of another
        size does too, but there a single entry is spread over the whole input, as numpy copies)."""
        for name, value in values.items():
            buffer, flat = self._args[self._parameter(name)], _flat(value)
            if flat.size != buffer.size:
                raise ValueError(self._size_error("parameter", name, buffer.size, flat.size))
            buffer[:] = flat

    def _check_sizes(self, args) -> None:
        """A ValueError naming the first of the call's inputs whose size is not its own (none: nothing)."""
        for i, (buffer, value) in enumerate(zip(self._inputs, args)):
            size = np.size(value)
            if size not in (1, buffer.size):
                raise ValueError(self._size_error("input", self._fn.name_in(i), buffer.size, size))

    def _size_error(self, kind: str, name: str, takes: int, given: int) -> str:
        return f"BufferedFunction: {kind} {name} of {self._fn.name()} takes {takes} floats, not {given}"

    def _parameter(self, name: str) -> int:
        i = self._parameters.get(name)
        if i is None:
            raise ValueError(f"BufferedFunction: {self._fn.name()} has no parameter {name!r} "
                             f"(its parameters: {', '.join(self._parameters) or 'none'})")
        return i

    def _dense(self, i: int, nonzeros: np.ndarray) -> np.ndarray:
        rows, cols = self._shapes[i]
        positions = self._scatter[i]
        if positions is None:
            flat = nonzeros.copy()
        else:
            flat = np.zeros(rows * cols)
            flat[positions] = nonzeros
        return np.ascontiguousarray(flat.reshape((rows, cols), order="F"))   # laid out as np.asarray(DM)


def _write(buffer: np.ndarray, value) -> None:
    """An input's value into its buffer, in column-major order."""
    buffer[:] = _flat(value)


def _flat(value) -> np.ndarray:
    """A value's entries in column-major order."""
    if isinstance(value, np.ndarray) and value.ndim < 2:
        return value                               # already in order: no column-major copy first
    return np.ravel(value, order="F")


def _dense_positions(sparsity: ca.Sparsity) -> np.ndarray | None:
    """Column-major positions of the structural nonzeros (None: the output is dense)."""
    if sparsity.is_dense():
        return None
    rows, cols = sparsity.get_triplet()
    return np.asarray(rows) + sparsity.size1() * np.asarray(cols)
