"""The file format of a stage cache entry: named numpy arrays and the entry's key, read in one
system call without parsing a zip archive.

An entry was an uncompressed ``.npz``; :func:`numpy.load` took 0.4-0.55 ms to read one of two
or three arrays (the zip directory, a CRC of each member, each member's ``.npy`` header parsed
by ``ast``), 8 % of the workers' time in a served ``fp6_grid`` re-run. This format reads in
≈ 0.03 ms: the file whole into one buffer, a JSON header, and each array a view of the buffer
(writable: the buffer is the array's own memory).

Layout: ``MAGIC`` (8 bytes), the header's length (8 bytes, little-endian), the header (UTF-8
JSON: ``{"key": ..., "arrays": [[name, dtype, shape, offset], ...]}``, dtypes as
:attr:`numpy.dtype.str`), then each array's C-ordered bytes at its offset (from the file's
start, aligned to :data:`ALIGN` bytes). Plain dtypes only (numbers, booleans, fixed-width
strings): an object or structured array is refused when written. A file that is not whole or
not this format raises :class:`EntryError` when read.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import BinaryIO

import numpy as np

#: First bytes of an entry file (its format and version).
MAGIC = b"TTCARR1\n"
#: Alignment of each array's bytes in the file (bytes).
ALIGN = 64
#: dtype kinds an entry may hold: bool, integers, floats, complex, bytes, unicode.
PLAIN_KINDS = frozenset("biufcSU")


class EntryError(ValueError):
    """The file is not a whole entry of this format."""


def _aligned(offset: int) -> int:
    return -(-offset // ALIGN) * ALIGN


def write_entry(handle: BinaryIO, key: str, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` and ``key`` to an open binary file (module docstring).

    Parameters
    ----------
    handle : a file opened for writing in binary mode, at its start.
    key : the entry's key (what its content depends on).
    arrays : name → array; plain dtypes only (``TypeError`` otherwise).
    """
    plain = {}
    for name, value in arrays.items():
        array = np.asarray(value, order="C")  # (ascontiguousarray makes 0-d arrays 1-d)
        if array.dtype.kind not in PLAIN_KINDS or array.dtype.fields is not None:
            raise TypeError(f"cache entry field {name!r}: dtype {array.dtype} is not storable")
        plain[name] = array
    reserved = ALIGN  # room for the header, grown until it fits
    while True:
        start = _aligned(len(MAGIC) + 8 + reserved)
        table, offset = [], start
        for name, array in plain.items():
            table.append([name, array.dtype.str, list(array.shape), offset])
            offset = _aligned(offset + array.nbytes)
        text = json.dumps({"key": key, "arrays": table}).encode()
        if len(text) <= start - len(MAGIC) - 8:
            break
        reserved = len(text)
    text = text.ljust(start - len(MAGIC) - 8)  # JSON allows the trailing spaces
    handle.write(MAGIC + len(text).to_bytes(8, "little") + text)
    position = start
    for (_, _, _, at), array in zip(table, plain.values(), strict=True):
        handle.write(b"\0" * (at - position))
        handle.write(array.tobytes())
        position = at + array.nbytes


def read_entry(path: Path) -> tuple[str, dict[str, np.ndarray]]:
    """(key, arrays) of an entry file; :class:`EntryError` when it is not a whole entry of
    this format, ``FileNotFoundError`` when it does not exist."""
    with open(path, "rb") as handle:
        size = handle.seek(0, 2)
        handle.seek(0)
        data = bytearray(size)
        if handle.readinto(data) != size:
            raise EntryError(f"{path}: short read")
    if data[: len(MAGIC)] != MAGIC or size < len(MAGIC) + 8:
        raise EntryError(f"{path}: not a cache entry")
    length = int.from_bytes(data[len(MAGIC) : len(MAGIC) + 8], "little")
    try:
        header = json.loads(data[len(MAGIC) + 8 : len(MAGIC) + 8 + length])
        key, table = str(header["key"]), header["arrays"]
        arrays = {}
        for name, descr, shape, offset in table:
            dtype = np.dtype(descr)
            if dtype.kind not in PLAIN_KINDS:
                raise EntryError(f"{path}: field {name!r} has dtype {descr}")
            count = math.prod(shape)
            if offset < 0 or offset + count * dtype.itemsize > size:
                raise EntryError(f"{path}: field {name!r} runs past the end (truncated)")
            flat = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            arrays[str(name)] = flat.reshape(tuple(shape))
    except (ValueError, KeyError, TypeError) as exc:  # JSON, dtype, shape: not whole
        raise EntryError(f"{path}: {exc}") from None
    return key, arrays
