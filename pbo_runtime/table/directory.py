"""The variable directory in a table's segment: one fixed record per variable, so a tool reads a live table without its YAML.

A record is DIRECTORY_RECORD bytes:

    name     NAME_BYTES bytes, UTF-8, NUL-padded (a longer name is cut)
    dtype    DTYPE_BYTES bytes, the numpy name (one of DTYPE_CODES), NUL-padded
    ints     8 int64: ndim, shape (MAX_DIMS sizes, unused ones 0), metadata word, data byte, nbytes

`table.table` writes the directory when it creates a table; `table.svar` reads it back from a live
one, checking every record against the segment it lies in: both through this module.
"""

from __future__ import annotations

import mmap
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pbo_runtime.errors import TableLayoutError

DIRECTORY_RECORD = 128  # bytes
NAME_BYTES = 48
DTYPE_BYTES = 16
MAX_DIMS = 4
META_WORDS = 3  # a variable's metadata words before its data: writer, sequence, write time
DTYPE_CODES = ("float64", "float32", "int64", "int32", "int16", "int8", "uint8", "uint16", "uint32", "uint64", "bool")

_INTS = NAME_BYTES + DTYPE_BYTES  # where the int64 words of a record start


@dataclass(frozen=True)
class Entry:
    """One variable as the directory describes it."""

    name: str
    dtype: np.dtype
    shape: tuple[int, ...]
    meta_word: int  # float64 word index of its META_WORDS metadata words
    data_byte: int  # byte offset of its data
    nbytes: int


def encode_record(entry: Entry) -> bytes:
    """One record."""
    record = bytearray(DIRECTORY_RECORD)
    name = entry.name.encode()[:NAME_BYTES]
    record[: len(name)] = name
    dtype = entry.dtype.name.encode()
    record[NAME_BYTES : NAME_BYTES + len(dtype)] = dtype
    shape = (list(entry.shape) + [0] * MAX_DIMS)[:MAX_DIMS]
    ints = np.array([len(entry.shape), *shape, entry.meta_word, entry.data_byte, entry.nbytes], dtype=np.int64)
    record[_INTS : _INTS + ints.nbytes] = ints.tobytes()
    return bytes(record)


def write_directory(buffer: mmap.mmap, offset: int, entries: Iterable[Entry]) -> None:
    """Write the records of `entries` into `buffer` (a writable mapping) from byte `offset` on."""
    for i, entry in enumerate(entries):
        base = offset + i * DIRECTORY_RECORD
        buffer[base : base + DIRECTORY_RECORD] = encode_record(entry)


def read_directory(table: str, buffer: mmap.mmap, count: int, offset: int, total: int, header_bytes: int) -> dict[str, Entry]:
    """The `count` records at byte `offset` of table `table`'s segment of `total` bytes, by name.

    The directory lies after the segment's header of `header_bytes`.
    Every record is checked against the segment: a dtype a table holds, a valid shape, a size
    that matches it, offsets inside the segment; TableLayoutError says which record and why.
    """
    if count < 0 or offset < header_bytes or offset + count * DIRECTORY_RECORD > total:
        raise TableLayoutError(f"table '{table}': its directory ({count} records at byte {offset}) lies outside the segment")
    entries: dict[str, Entry] = {}
    for i in range(count):
        base = offset + i * DIRECTORY_RECORD
        entry = _decode_record(table, i, bytes(buffer[base : base + DIRECTORY_RECORD]), total)
        entries[entry.name] = entry
    return entries


def _decode_record(table: str, index: int, record: bytes, total: int) -> Entry:
    name = record[:NAME_BYTES].split(b"\0", 1)[0].decode(errors="replace")
    code = record[NAME_BYTES:_INTS].split(b"\0", 1)[0].decode(errors="replace")
    ints = np.frombuffer(record[_INTS:], dtype=np.int64)
    ndim = int(ints[0])
    shape = tuple(int(n) for n in ints[1 : 1 + min(max(ndim, 0), MAX_DIMS)])
    meta_word, data_byte, nbytes = (int(n) for n in ints[1 + MAX_DIMS : 4 + MAX_DIMS])
    where = f"table '{table}', directory record {index} ('{name}')"
    if code not in DTYPE_CODES:
        raise TableLayoutError(f"{where}: dtype '{code}' is not one a table holds ({', '.join(DTYPE_CODES)})")
    dtype = np.dtype(code)
    if not 0 <= ndim <= MAX_DIMS or any(n < 0 for n in shape):
        raise TableLayoutError(f"{where}: shape {shape} of {ndim} dimensions is not valid")
    if nbytes != int(np.prod(shape, dtype=np.int64)) * dtype.itemsize:
        raise TableLayoutError(f"{where}: {nbytes} bytes do not hold a {dtype.name} array of shape {shape}")
    if not (meta_word >= 0 and (meta_word + META_WORDS) * 8 <= total and data_byte % dtype.itemsize == 0
            and data_byte >= 0 and data_byte + nbytes <= total):
        raise TableLayoutError(f"{where}: its offsets (metadata word {meta_word}, data byte {data_byte}) lie outside the segment")
    return Entry(name, dtype, shape, meta_word, data_byte, nbytes)
