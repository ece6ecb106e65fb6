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


def params_model():
    x, p, q = ca.SX.sym("x", 2), ca.SX.sym("p", 2, 2), ca.SX.sym("q")
    return ca.Function("m4_test_params", [x, p, q], [ca.mtimes(p, x) * q], ["x", "p", "q"], ["y"])


def test_parameters_are_set_by_name_and_kept_between_calls():
    fn = BufferedFunction(params_model(), parameters=2)
    fn.set_parameters(p=np.array([[1.0, 2.0], [3.0, 4.0]]), q=10.0)
    (first,) = fn(np.array([1.0, 0.0]))
    fn.set_parameters(q=1.0)
    (second,) = fn(np.array([0.0, 1.0]))
    assert np.array_equal(first.ravel(), [10.0, 30.0]) and np.array_equal(second.ravel(), [2.0, 4.0])


def test_a_shared_parameter_is_written_by_either_function():
    owner = BufferedFunction(params_model(), parameters=2)
    other = BufferedFunction(params_model(), parameters=2, shared={"p": owner.buffer("p")})
    owner.set_parameters(p=np.eye(2), q=1.0)
    other.set_parameters(q=2.0)
    assert np.array_equal(other(np.array([1.0, 3.0]))[0].ravel(), [2.0, 6.0])


def test_a_parameter_is_named_or_refused_by_name():
    fn = BufferedFunction(params_model(), parameters=1)
    with pytest.raises(ValueError, match="m4_test_params has no parameter 'p' \\(its parameters: q\\)"):
        fn.set_parameters(p=np.eye(2))
    with pytest.raises(ValueError, match="m4_test_params has 3 inputs, not 4 parameters"):
        BufferedFunction(params_model(), parameters=4)


def test_a_value_of_the_wrong_size_is_refused_in_one_line_naming_it_and_the_sizes():
    fn = BufferedFunction(params_model(), parameters=2)
    with pytest.raises(ValueError, match="^BufferedFunction: parameter p of m4_test_params takes 4 floats, not 3$"):
        fn.set_parameters(p=np.ones(3))
    with pytest.raises(ValueError, match="^BufferedFunction: parameter q of m4_test_params takes 1 floats, not 2$"):
        fn.set_parameters(q=[1.0, 2.0])
    with pytest.raises(ValueError, match="^BufferedFunction: parameter p of m4_test_params takes 4 floats, not 1$"):
        fn.set_parameters(p=1.0)                   # not spread over the matrix
    with pytest.raises(ValueError, match="^BufferedFunction: input x of m4_test_params takes 2 floats, not 3$"):
        fn(np.ones(3))


def test_the_inputs_are_written_where_compiled_code_reads_them_and_the_results_lie_where_it_writes():
    fn = BufferedFunction(model())
    inputs, results = fn.buffers()
    fn.set_inputs(np.array([0.3, -1.2, 2.5]), 0.7)
    assert np.array_equal(inputs[0], [0.3, -1.2, 2.5]) and np.array_equal(inputs[1], [0.7])
    assert all(got is kept for got, kept in zip(fn.evaluate(inputs[0].copy(), 0.7), results, strict=True))
