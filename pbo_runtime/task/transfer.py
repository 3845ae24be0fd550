"""A task's local state variable table and its precomputed transfers (TR §4.2, Figure 11).

Everything is worked out at spawn: one contiguous local buffer per dtype and direction, each
port's array a view into it, and for the per-cycle transfers one index array per dtype. A
cycle's read is then `lock; take(idx, out=local); unlock` and its write is
`lock; sequence odd; flat[idx] = local; sequence even; unlock`: no name lookup, no allocation.
The sequence is the seqlock observers read the table under without the lock (`table.snapshot`);
its odd value names the writer, so it also signs the lock (`ipc.segment`): a write costs two
integer stores and a load, as a read costs its one store of the holder word.

Local float64 buffers are laid out as
    [writer x k][float64 data ...][status block (per-cycle outputs only)]
The writer words name this task on every output; the status block carries the cycle count and
release time, which are the outputs' sequence number and write time (see `table.table`), so a
write is stamped by the same scatter that moves it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import posix_ipc

from pbo_runtime.config.model import PortBinding
from pbo_runtime.objects.ports import PortKind
from pbo_runtime.objects.waits import sleep_while_cycling
from pbo_runtime.table.directory import META_WORDS
from pbo_runtime.table.table import HEADER_WORDS, STATUS_WORDS, Header, StateTable, StatusWord

# np.count_nonzero's C function without its Python wrapper, which only dispatches on axis and
# keepdims: the wrapper cost about 0.3 µs of the finite check's ~1 µs per cycle (2 vCPUs, loaded).
_COUNT_NONZERO = getattr(getattr(getattr(np, "_core", None), "multiarray", None), "count_nonzero", np.count_nonzero)

_INPUT_ORDER = (PortKind.IN_CONST, PortKind.IN_BOTH, PortKind.IN_VAR)
_OUTPUT_ORDER = (PortKind.OUT_CONST, PortKind.OUT_BOTH, PortKind.OUT_VAR)


@dataclass
class _Group:
    """One dtype's share of a transfer: global view, global indices, local buffer."""

    flat: np.ndarray
    index: np.ndarray
    local: np.ndarray


class _Region:
    """The local copies of a set of bindings, with the global indices they map to."""

    def __init__(self, table: StateTable, bindings: list[PortBinding], writer: int, status_words: int,
                 freshness: bool = False) -> None:
        layout = table.layout
        slots = [layout.slot(b.variable) for b in bindings]
        k = len(bindings)
        f64 = np.dtype("float64")
        index64: list[int] = [s.meta_word for s in slots]
        other: dict[str, list[int]] = {}
        data_pos: list[tuple[str, int]] = []
        for s in slots:
            target = index64 if s.dtype == f64 else other.setdefault(s.dtype.name, [])
            data_pos.append((s.dtype.name, len(target)))
            target.extend(range(s.data_index, s.data_index + s.size))
        self.status_at = len(index64)
        # Inputs of a task that watches freshness also gather each writer's release time (the
        # write time of what is read); the executive points these at the current writers.
        self.freshness_at = len(index64)
        if freshness:
            index64.extend([HEADER_WORDS - 1] * k)  # an unused header word (0.0) until retargeted
        if status_words:
            first = layout.status_offset // 8 + writer * STATUS_WORDS
            index64.extend(range(first, first + status_words))
        self.groups: list[_Group] = []
        locals_by_dtype: dict[str, np.ndarray] = {}
        for dtype_name, idx in [("float64", index64), *other.items()]:
            local = np.zeros(len(idx), dtype=dtype_name)
            locals_by_dtype[dtype_name] = local
            if idx:
                self.groups.append(_Group(table.dtype_view(np.dtype(dtype_name)), np.asarray(idx, dtype=np.intp), local))
        local64 = locals_by_dtype["float64"]
        self.writer = local64[0:k]
        self.writer.fill(writer)
        self.status = local64[self.status_at : self.status_at + status_words]
        self.write_times = local64[self.freshness_at : self.freshness_at + (k if freshness else 0)]
        # the variables' data alone, one contiguous view per float dtype (no writer words, no status)
        self.float_data = [local64[k : self.status_at]]
        self.float_data += [local for name, local in locals_by_dtype.items() if name != "float64" and local.dtype.kind == "f"]
        self.freshness_index = (
            self.groups[0].index[self.freshness_at : self.freshness_at + k] if freshness and self.groups else None
        )
        self.arrays = [
            locals_by_dtype[dtype_name][pos : pos + s.size].reshape(s.shape)
            for (dtype_name, pos), s in zip(data_pos, slots, strict=True)
        ]


class LocalTable:
    """A task's private copies of its variables, and the transfers Figure 11 prescribes."""

    def __init__(self, table: StateTable, bindings: tuple[PortBinding, ...], task_index: int,
                 watch_freshness: bool = False) -> None:
        self.table = table
        self.task_index = task_index
        inputs = sorted((b for b in bindings if b.port.kind.is_input), key=lambda b: _INPUT_ORDER.index(b.port.kind))
        outputs = sorted((b for b in bindings if not b.port.kind.is_input), key=lambda b: _OUTPUT_ORDER.index(b.port.kind))
        in_const = [b for b in inputs if b.port.kind.at_init]
        in_var = [b for b in inputs if b.port.kind.every_cycle]
        out_const = [b for b in outputs if b.port.kind.at_init]
        out_var = [b for b in outputs if b.port.kind.every_cycle]
        # Consts move once, at init; a `both` port has one local copy shared by both regions.
        # (in a live spawn the RTPU's due cycles run between the regions made: `sleep_while_cycling`)
        self._in_const = _Region(table, in_const, task_index, 0)
        sleep_while_cycling(0)
        self._in_var = _Region(table, in_var, task_index, 0, freshness=watch_freshness)
        sleep_while_cycling(0)
        self._out_const = _Region(table, out_const, task_index, 0)
        sleep_while_cycling(0)
        self._out_var = _Region(table, out_var, task_index, int(StatusWord.USED))
        sleep_while_cycling(0)
        by_binding: dict[int, np.ndarray] = {}
        for region, members in (
            (self._in_var, in_var),
            (self._in_const, in_const),
            (self._out_var, out_var),
            (self._out_const, out_const),
        ):
            for binding, array in zip(members, region.arrays, strict=True):
                by_binding.setdefault(id(binding), array)
        self._both_in = [(self._in_const.arrays[in_const.index(b)], by_binding[id(b)]) for b in in_const if b in in_var]
        self._both_out = [(self._out_const.arrays[out_const.index(b)], by_binding[id(b)]) for b in out_const if b in out_var]
        self.port_arrays = [by_binding[id(b)] for b in bindings]
        self.status = self._out_var.status  # the executive's counters, written with the outputs
        self.input_writer = self._in_var.writer  # who wrote each in-var, as of the last read
        self.input_variables = tuple(b.variable for b in in_var)
        self._out_variables = tuple(b.variable for b in out_var)
        self.input_write_times = self._in_var.write_times  # with watch_freshness: each writer's last release
        self.bytes_in = sum(a.nbytes for a in self._in_var.arrays)  # the data of the per-cycle ports
        self.bytes_out = sum(a.nbytes for a in self._out_var.arrays)
        # what a cycle really moves: the data, each variable's writer word, the status block
        self.bytes_moved = sum(g.index.size * g.local.itemsize for g in (*self._in_var.groups, *self._out_var.groups))
        self._lock = table.lock
        self._lock_words = table.lock_words
        self._writer_tag = table.writer_tag
        self._pid = table._pid
        self._compile()

    def watch_writers(self, writers: list[int]) -> None:
        """Gather, with the inputs, the release time of these tasks (one per in-var; -1: none).

        Called at `on` and at a switch, never per cycle; it rewrites index entries in place.
        """
        index = self._in_var.freshness_index
        if index is None:
            return
        status_base = self.table.layout.status_offset // 8
        for position, writer in enumerate(writers):
            # a variable job control writes has no producer period: point at an unused word (0.0)
            index[position] = status_base + writer * STATUS_WORDS + int(StatusWord.RELEASE) if writer >= 0 else HEADER_WORDS - 1

    def _compile(self) -> None:
        """Bind the per-cycle transfers to locals so a call does no attribute chasing.

        Each waits for the lock as long as the table's `cycle_lock_wait` says, and returns
        False, having moved nothing, when that wait ran out (a holder that died holding it).
        """
        acquire = self._lock.acquire
        release = self._lock.release
        wait = self.table.cycle_lock_wait  # [seconds or None], read at every transfer
        busy = posix_ipc.BusyError
        words = self._lock_words  # a memoryview: its stores cost about half a numpy array's
        holder = int(Header.LOCK_HOLDER)
        sequence_word = int(Header.LOCK_SEQUENCE)
        pid = self._pid
        tag = self._writer_tag
        in_groups = tuple((g.flat.take, g.index, g.local) for g in self._in_var.groups)
        out_groups = tuple((g.flat, g.index, g.local) for g in self._out_var.groups)

        if len(in_groups) == 1:
            (take, idx, local), = in_groups

            def read_inputs() -> bool:
                try:
                    acquire(wait[0])
                except busy:
                    return False
                words[holder] = pid
                take(idx, None, local, "clip")  # (positional: keywords are parsed at every call)
                release()
                return True
        else:

            def read_inputs() -> bool:
                try:
                    acquire(wait[0])
                except busy:
                    return False
                words[holder] = pid
                for take, idx, local in in_groups:
                    take(idx, None, local, "clip")
                release()
                return True

        if len(out_groups) == 1:
            (flat, oidx, olocal), = out_groups

            def write_outputs() -> bool:
                try:
                    acquire(wait[0])
                except busy:
                    return False
                before = words[sequence_word]
                words[sequence_word] = tag  # odd, and naming this process: observers retry, the lock is signed
                flat[oidx] = olocal
                words[sequence_word] = before + 2
                release()
                return True
        else:

            def write_outputs() -> bool:
                try:
                    acquire(wait[0])
                except busy:
                    return False
                before = words[sequence_word]
                words[sequence_word] = tag
                for flat, idx, local in out_groups:
                    flat[idx] = local
                words[sequence_word] = before + 2
                release()
                return True

        self.read_inputs = read_inputs
        self.write_outputs = write_outputs
        self.outputs_finite = self._finite_check()

    def _finite_check(self) -> Callable[[], bool]:
        """The per-cycle test that every float out-var is finite, before the outputs are written.

        `np.isfinite` into a mask made here, then `np.count_nonzero` of it (a Python int): two C
        calls per float dtype, no array allocated, no floating-point warning. (A dot product with
        zeros, NaN when an element is not finite, measured about as fast but allocates its result
        and warns on Inf; `mask.all()` allocates on each call, in its Python wrapper.) Only the
        variables' data is tested, not the writer words or the status block; integer buffers
        cannot hold a non-finite number.
        """
        isfinite, count_nonzero = np.isfinite, _COUNT_NONZERO
        checks = tuple((data, np.zeros(data.size, dtype=bool), data.size) for data in self._out_var.float_data if data.size)
        if len(checks) == 1:
            (data, mask, size), = checks

            def outputs_finite() -> bool:
                isfinite(data, mask)  # the mask given positionally: an out= keyword is parsed at every call
                return count_nonzero(mask) == size  # type: ignore[no-any-return]
        else:

            def outputs_finite() -> bool:
                for data, mask, size in checks:
                    isfinite(data, mask)
                    if count_nonzero(mask) != size:
                        return False
                return True

        return outputs_finite

    def non_finite_outputs(self) -> list[str]:
        """The out-vars that hold NaN or Inf now, for the error message (not per cycle)."""
        return [variable for variable, array in zip(self._out_variables, self._out_var.arrays, strict=True)
                if array.dtype.kind == "f" and not np.isfinite(array).all()]

    # --- the transfers of Figure 11 that are not per cycle -----------------------------------

    def read_consts(self) -> None:
        """In-consts (and in-boths) before `init`."""
        self._gather(self._in_const)
        for const_copy, var_copy in self._both_in:
            var_copy[...] = const_copy

    def write_consts(self) -> None:
        """Out-consts (and out-boths) after `init`, with the status block (their write time)."""
        for const_copy, var_copy in self._both_out:
            const_copy[...] = var_copy
        self._scatter(self._out_const)
        self.write_status()

    def read_for_on(self) -> None:
        """In-vars and out-vars before `on`: take over the current state of the system."""
        self.table.acquire()
        try:
            for region in (self._in_var, self._out_var):
                for g in region.groups:
                    if region is self._out_var:
                        # Leave the status block alone: it is ours, not the table's history.
                        n = region.status_at if g.local is region.groups[0].local else len(g.index)
                        g.flat.take(g.index[:n], out=g.local[:n], mode="clip")
                    else:
                        g.flat.take(g.index, out=g.local, mode="clip")
        finally:
            self.table.release()
        self._out_var.writer.fill(self.task_index)

    def publish_outputs(self) -> None:
        """The out-vars and the status block, waiting for the lock as long as it takes: the values
        `on` and `off` leave must reach the table, however long a per-cycle transfer may wait."""
        self._scatter(self._out_var)

    def write_status(self) -> None:
        """Publish the status block alone (a state change outside the cycle)."""
        region = self._out_var
        first = self.table.layout.status_offset // 8 + self.task_index * STATUS_WORDS
        self.table.acquire()
        try:
            before = self.table.begin_write()
            self.table.words[first : first + region.status.size] = region.status
            self.table.end_write(before)
        finally:
            self.table.release()

    def _gather(self, region: _Region) -> None:
        self.table.acquire()
        try:
            for g in region.groups:
                g.flat.take(g.index, out=g.local, mode="clip")
        finally:
            self.table.release()

    def _scatter(self, region: _Region) -> None:
        self.table.acquire()
        try:
            before = self.table.begin_write()
            for g in region.groups:
                g.flat[g.index] = g.local
            self.table.end_write(before)
        finally:
            self.table.release()


__all__ = ["META_WORDS", "LocalTable"]
