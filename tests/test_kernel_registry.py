"""Every compiled kernel has a plain-numpy reference, and the two agree (`control.kernel_registry`).

The registry test enumerates every numba dispatcher defined in a `control.kernels` module (and in an
`app.sim` module): one that is not in `KERNELS` (`app.sim.kernel_registry.SIM_KERNELS`) fails. No
compiled function (the kernels and the simulator's) takes more than `MAX_ARGUMENTS` arguments, nor
more than `MAX_ARGUMENTS` values counting a tuple as its members (as the registry's samples call it):
a group of them is a named record (`control.kernels.records`).

Each pair runs on the same copies of its sample inputs; every output and every argument array the
kernel writes (scratch excepted; a record's fields each) is held to the entry's relative tolerance
(1e-10, or max(1e-10, 100·eps·κ) for outputs derived from an ill-conditioned inverse: see
`tests/test_kernels.py`); booleans, integers and NaN positions exactly.
"""

from __future__ import annotations

import copy
import importlib
import inspect
import pkgutil
import zlib

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

import app.sim
import control.kernels
from app.sim.kernel_registry import SIM_KERNELS
from control.kernel_registry import KERNELS

MAX_ARGUMENTS = 10  # per compiled function; more than this: group them into a record


def _dispatchers(package=control.kernels) -> dict[str, CPUDispatcher]:
    found = {}
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__:
                found[f"{module.__name__}.{name}" if package is not control.kernels else name] = value
    return found


def test_no_compiled_function_takes_more_than_ten_arguments():
    counts = {
        name: len(inspect.signature(f.py_func).parameters)
        for name, f in {**_dispatchers(), **_dispatchers(app.sim)}.items()
    }
    assert len(counts) >= 45  # the kernels and the simulator's compiled functions were found
    over = {name: n for name, n in counts.items() if n > MAX_ARGUMENTS}
    assert not over, f"compiled functions over {MAX_ARGUMENTS} arguments (group them into a record): {over}"


def test_no_compiled_function_takes_more_than_ten_values_counting_the_members_of_tuples():
    """A tuple argument counts as its members (a record as one value): the arguments of every sample
    call of every registered kernel, the simulator's too, hold at most `MAX_ARGUMENTS` values."""
    counts = {}
    for name, pair in {**KERNELS, **SIM_KERNELS}.items():
        samples = pair.samples(np.random.default_rng(zlib.crc32(name.encode())))
        counts[name] = max(len(_leaves(args)) for args in samples)
    assert len(counts) >= 45
    assert max(counts.values()) > 1  # the count reached into the samples
    over = {name: n for name, n in counts.items() if n > MAX_ARGUMENTS}
    assert not over, f"compiled functions given over {MAX_ARGUMENTS} values (group them into a record): {over}"


def test_every_compiled_kernel_has_a_reference_in_the_registry():
    dispatchers = _dispatchers()
    assert len(dispatchers) >= 40
    missing = sorted(set(dispatchers) - set(KERNELS))
    assert not missing, f"compiled kernels without a reference in control.kernel_registry: {missing}"
    for name, pair in KERNELS.items():
        assert pair.compiled is dispatchers[name], name
        assert not isinstance(pair.reference, CPUDispatcher), name


def test_every_compiled_function_of_the_simulator_has_a_reference_in_its_registry():
    dispatchers = _dispatchers(app.sim)
    assert len(dispatchers) >= 5
    missing = sorted(set(dispatchers) - set(SIM_KERNELS))
    assert not missing, f"compiled functions without a reference in app.sim.kernel_registry: {missing}"
    for name, pair in SIM_KERNELS.items():
        assert pair.compiled is dispatchers[name], name
        assert not isinstance(pair.reference, CPUDispatcher), name


def _leaves(value) -> list:
    if isinstance(value, (tuple, list)):
        return [leaf for item in value for leaf in _leaves(item)]
    return [value]


def _assert_close(a, b, tol: float, what: str) -> None:
    if b is None or isinstance(b, (bool, np.bool_, int, np.integer)):
        assert a == b, (what, a, b)
        return
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (what, a.shape, b.shape)
    nan = np.isnan(b)
    assert np.array_equal(np.isnan(a), nan), (what, "NaN positions differ")
    a, b = a[~nan], b[~nan]
    if b.size == 0:
        return
    inf = np.isinf(b)
    assert np.array_equal(a[inf], b[inf]), what
    err = float(np.max(np.abs(a[~inf] - b[~inf]), initial=0.0))
    scale = max(float(np.max(np.abs(b[~inf]), initial=0.0)), 1e-300)
    assert err <= tol * scale, (what, err / scale, tol)


@pytest.mark.parametrize("name", sorted(KERNELS) + sorted(SIM_KERNELS))
def test_compiled_kernel_equals_its_reference(name):
    pair = KERNELS[name] if name in KERNELS else SIM_KERNELS[name]
    samples = pair.samples(np.random.default_rng(zlib.crc32(name.encode())))
    assert samples, name
    for k, args in enumerate(samples):
        compiled_args, reference_args = copy.deepcopy(args), copy.deepcopy(args)
        out, ref = pair.compiled(*compiled_args), pair.reference(*reference_args)
        tol = pair.tolerance(args)
        out_leaves, ref_leaves = _leaves(out), _leaves(ref)
        assert len(out_leaves) == len(ref_leaves), (name, k)
        for i, (a, b) in enumerate(zip(out_leaves, ref_leaves, strict=True)):
            _assert_close(a, b, tol, f"{name} sample {k} output {i}")
        for i, (a, b) in enumerate(zip(compiled_args, reference_args, strict=True)):
            if i in pair.scratch:
                continue
            for j, (a_leaf, b_leaf) in enumerate(zip(_leaves(a), _leaves(b), strict=True)):  # a tuple's arrays too
                if not isinstance(b_leaf, np.ndarray):
                    continue
                for field in b_leaf.dtype.names or (None,):  # a record: each of its fields
                    a_val, b_val = (a_leaf, b_leaf) if field is None else (a_leaf[field], b_leaf[field])
                    _assert_close(a_val, b_val, tol, f"{name} sample {k} argument {i}.{j} {field or ''}")
