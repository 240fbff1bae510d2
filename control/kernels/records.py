"""Named records at the compiled boundary: what a kernel reads of a parameter group, by field name.

A record is a numpy structured dtype (a numba `Record` inside a kernel), generated from the fields
of the parameter groups it carries: every numeric scalar field (float, int, bool) of each group
becomes a field of the same name, so a new gain is in the record as soon as it is in its dataclass.
Beside them, `derived` fields hold what the executor computes from the groups and the robot (the
force/motion permutation, the per-axis gains, the joint limits), each named and shaped once.

A kernel takes the record as a one-element array `rec` and reads `rec[0].force_kp`; numba checks a
structured argument as cheaply as a plain array (one more argument costs about 0.05 µs a call here,
`rec[0]` nothing): the named form costs no more than the positional arrays it replaces. A jitclass
or a structref would give the same names, but their attributes are set from Python one compiled
setter at a time, and they pickle (the sweep's worker processes) only with extra code.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

# a dataclass field's annotation (a string: `from __future__ import annotations`) → its record type
_SCALAR_TYPES = {"float": np.float64, "int": np.int64, "bool": np.bool_}


def group_fields(group: type) -> list[tuple[str, Any]]:
    """(name, numpy type) of every numeric scalar field of a parameter-group dataclass, in order."""
    out = []
    for f in dataclasses.fields(group):
        kind = _SCALAR_TYPES.get(f.type if isinstance(f.type, str) else getattr(f.type, "__name__", ""))
        if kind is not None:
            out.append((f.name, kind))
    return out


def record_dtype(groups: tuple[type, ...], derived: tuple[tuple, ...] = ()) -> np.dtype:
    """The structured dtype of the record of `groups` (their `group_fields`) and `derived` fields
    ((name, type) or (name, type, shape)); ValueError when two of them share a name."""
    spec: list[tuple] = [field for group in groups for field in group_fields(group)]
    spec += list(derived)
    names = [s[0] for s in spec]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"record fields named twice: {', '.join(twice)}")
    return np.dtype(spec, align=True)


def fill_record(dtype: np.dtype, groups: tuple[Any, ...], **derived: Any) -> np.ndarray:
    """A one-element record array of `dtype`: each group's fields by name, then the derived ones
    (every derived field of the dtype must be given; a subarray field may be given shorter, the
    rest stays zero). ValueError naming a missing or unknown derived field."""
    rec = np.zeros(1, dtype)
    row = rec[0]
    from_groups = set()
    for group in groups:
        for name, _ in group_fields(type(group)):
            row[name] = getattr(group, name)
            from_groups.add(name)
    names = dtype.names or ()
    wanted = [n for n in names if n not in from_groups]
    missing = sorted(set(wanted) - set(derived))
    unknown = sorted(set(derived) - set(wanted))
    if missing or unknown:
        raise ValueError(f"record {dtype}: missing {missing}, unknown {unknown}")
    fields: Mapping[str, Any] = dtype.fields or {}
    for name, value in derived.items():
        shape = fields[name][0].shape
        if shape and np.ndim(value) == 1 and len(value) < shape[0]:
            row[name][: len(value)] = value
        else:
            row[name] = value
    return rec


def record_values(rec: np.ndarray) -> dict[str, Any]:
    """Every field of a one-element record as a Python value (scalars) or an array copy."""
    row = rec[0]
    out: dict[str, Any] = {}
    for name in rec.dtype.names or ():
        value = row[name]
        out[name] = np.array(value) if np.ndim(value) else value.item()
    return out


def group_of(group: type, values: Mapping[str, Any], base: Any) -> Any:
    """`base` (an instance of `group`) with its record fields set from `values` (the way back of
    `fill_record`, for the round-trip tests)."""
    return dataclasses.replace(base, **{name: values[name] for name, _ in group_fields(group)})


# A task target's arrays and their shapes: the fields of its record (`target_record_dtype`), which
# `control.executor.TaskTarget` keeps its arrays in and hands to the kernels (`target.record`).
TARGET_FIELDS = (("position", (3,)), ("rotation", (3, 3)), ("velocity", (6,)), ("acceleration", (6,)), ("wrench", (6,)))


@functools.cache
def target_record_dtype() -> np.dtype:
    """The record of a task target (`control.executor.TaskTarget`): p° (3,), R° (3, 3), ẋ° (6,), ẍ° (6,)
    and F̂ (6,) by name (`target[0].velocity` in a kernel)."""
    return record_dtype((), tuple((name, np.float64, shape) for name, shape in TARGET_FIELDS))


class RecordBlocks:
    """One-element records of `dtype` handed out one by one from blocks of `size`, for a builder that
    makes one record per control step (a record of its own costs about 1.5 µs to allocate, a slice of
    a block 0.1 µs; `control.model.SnapshotRecords` does the same for the snapshots): each record is
    a one-element slice of a block, never handed out twice; a block lives as long as one of its
    records does. With a `template` each record starts as a copy of it, so a builder writes only the
    fields that change from step to step."""

    def __init__(self, dtype: np.dtype, size: int = 64, template: np.ndarray | None = None):
        self.dtype, self.size = dtype, size
        self.template = template
        self._new_block()

    def _new_block(self) -> None:
        self.block = np.empty(self.size, self.dtype)
        if self.template is not None:  # every record starts as the template (one copy per block)
            self.block[:] = self.template
        self.fields = {name: self.block[name] for name in self.dtype.names or ()}
        self.next = 0

    def refill(self, template: np.ndarray | None) -> None:
        """Records handed out from now on start as `template` (a one-element record of the dtype;
        None: not initialised); those handed out before keep their values."""
        self.template = template
        self._new_block()

    def take(self) -> tuple[np.ndarray, dict[str, np.ndarray], int]:
        """(record, the block's field arrays, the record's index in them): write the record's fields
        as `fields[name][at] = value` (they hold the template's values, or nothing defined without one)."""
        if self.next == self.size:
            self._new_block()
        at = self.next
        self.next = at + 1
        return self.block[at : at + 1], self.fields, at


def target_record(position, rotation, velocity, acceleration, wrench) -> np.ndarray:
    """A one-element target record holding copies of the five arrays (for tests and samples)."""
    rec = np.empty(1, target_record_dtype())
    rec[0] = (position, rotation, velocity, acceleration, wrench)
    return rec
