"""Compiled CasADi functions: built once, cached by a hash of the code, reused without a compiler."""

import ctypes

import casadi as ca
import numpy as np
import pytest

from companion.core import codegen_cache


def square_plus(c):
    x = ca.SX.sym("x", 2)
    return ca.Function("m4_test_square", [x], [x ** 2 + c])


def test_the_compiled_function_computes_what_the_symbolic_one_does(tmp_path, monkeypatch):
    monkeypatch.setenv(codegen_cache.CACHE_ENV, str(tmp_path))
    fn = codegen_cache.compiled(square_plus(1.0))
    assert np.asarray(fn([2.0, 3.0])).ravel() == pytest.approx([5.0, 10.0])
    assert len(list(tmp_path.glob("m4_test_square_*.so"))) == 1


def test_a_cached_library_is_loaded_without_compiling_again(tmp_path, monkeypatch):
    monkeypatch.setenv(codegen_cache.CACHE_ENV, str(tmp_path))
    codegen_cache.compiled(square_plus(1.0))

    def no_compiler(*args, **kwargs):
        raise AssertionError("compiled again")

    monkeypatch.setattr(codegen_cache.subprocess, "run", no_compiler)
    fn = codegen_cache.compiled(square_plus(1.0))
    assert np.asarray(fn([1.0, 1.0])).ravel() == pytest.approx([2.0, 2.0])


def test_a_changed_problem_gets_its_own_library(tmp_path, monkeypatch):
    monkeypatch.setenv(codegen_cache.CACHE_ENV, str(tmp_path))
    codegen_cache.compiled(square_plus(1.0))
    fn = codegen_cache.compiled(square_plus(2.0))
    assert np.asarray(fn([0.0, 0.0])).ravel() == pytest.approx([2.0, 2.0])
    assert len(list(tmp_path.glob("m4_test_square_*.so"))) == 2


def test_a_missing_compiler_is_reported_clearly(tmp_path, monkeypatch):
    monkeypatch.setenv(codegen_cache.CACHE_ENV, str(tmp_path))
    monkeypatch.setenv("CC", "")
    monkeypatch.setattr(codegen_cache.shutil, "which", lambda name: None)
    with pytest.raises(codegen_cache.CodegenError, match="no C compiler"):
        codegen_cache.compiled(square_plus(1.0))


def test_an_unwritable_cache_directory_is_reported_by_name(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    monkeypatch.setenv(codegen_cache.CACHE_ENV, str(blocker / "cache"))
    with pytest.raises(codegen_cache.CodegenError, match=codegen_cache.CACHE_ENV):
        codegen_cache.compiled(square_plus(3.0))


TWICE_C = """
typedef long long casadi_int;
int m4_test_square(const double** arg, double** res, casadi_int* iw, double* w, int mem);
int m4_test_twice(const double* x, double* y) {
    const double* arg[1] = {x};
    double* res[1] = {y};
    int flag = m4_test_square(arg, res, 0, 0, 0);
    y[0] *= SCALE;
    y[1] *= SCALE;
    return flag;
}
"""


def test_a_library_holds_the_generated_code_with_our_c_source_and_flags_and_is_keyed_by_them(tmp_path, monkeypatch):
    monkeypatch.setenv(codegen_cache.CACHE_ENV, str(tmp_path / "cache"))
    source = tmp_path / "twice.c"
    source.write_text(TWICE_C)

    def twice(scale):
        lib = codegen_cache.compiled_library("m4_test_twice", [square_plus(1.0)], (source,), (f"-DSCALE={scale}",))
        x, y = np.array([2.0, 3.0]), np.zeros(2)
        assert ctypes.CDLL(str(lib)).m4_test_twice(x.ctypes.data_as(ctypes.c_void_p), y.ctypes.data_as(ctypes.c_void_p)) == 0
        assert np.asarray(ca.external("m4_test_square", str(lib))([2.0, 3.0])).ravel() == pytest.approx([5.0, 10.0])
        return y

    assert twice(2.0) == pytest.approx([10.0, 20.0])
    assert twice(3.0) == pytest.approx([15.0, 30.0])
    assert len(list((tmp_path / "cache").glob("m4_test_twice_*.so"))) == 2
