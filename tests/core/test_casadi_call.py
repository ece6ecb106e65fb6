"""CasADi functions called on numpy buffers: the function's own values, shaped like np.asarray(DM)."""

import casadi as ca
import numpy as np
import pytest

from companion.core.casadi_call import BufferedFunction


def model():
    x, t = ca.SX.sym("x", 3), ca.SX.sym("t")
    y = ca.vertcat(ca.sin(x[0]) * t, x[1] * x[2])
    return ca.Function("m4_test_model", [x, t], [y, ca.jacobian(y, x), ca.reshape(x, 1, 3)])


def test_outputs_equal_the_direct_call_bit_for_bit_with_sparse_outputs_made_dense():
    fn = model()
    x, t = np.array([0.3, -1.2, 2.5]), 0.7
    direct = [np.asarray(v) for v in fn(x, t)]
    buffered = BufferedFunction(fn)(x, t)
    assert [v.shape for v in buffered] == [(2, 1), (2, 3), (1, 3)]
    for got, want in zip(buffered, direct, strict=True):
        assert np.array_equal(got, want)
        assert got.flags["C_CONTIGUOUS"]


def test_each_call_returns_fresh_arrays():
    fn = BufferedFunction(model())
    first = fn(np.array([0.3, -1.2, 2.5]), 0.7)[0].copy()
    kept = fn(np.array([0.3, -1.2, 2.5]), 0.7)[0]
    fn(np.array([1.0, 1.0, 1.0]), 2.0)
    assert np.array_equal(kept, first)


def test_a_matrix_input_is_read_in_column_major_order():
    m = ca.SX.sym("m", 2, 3)
    fn = BufferedFunction(ca.Function("m4_test_row", [m], [m[0, :]]))
    (row,) = fn(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]))
    assert np.array_equal(row, [[1.0, 2.0, 3.0]])


def test_a_sparse_input_is_refused():
    x = ca.SX.sym("x", ca.Sparsity.diag(2))
    with pytest.raises(ValueError, match="dense"):
        BufferedFunction(ca.Function("m4_test_sparse_in", [x], [ca.sum1(x)]))
