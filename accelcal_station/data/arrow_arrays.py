"""numpy <-> Arrow arrays through their buffers, not through pyarrow's pandas bridge.

``pa.array``, ``pa.scalar`` and ``Array.to_numpy`` go through pyarrow's pandas compatibility layer,
which imports pandas wherever pandas is installed: about 0.5 CPU-s, most of a small lot's start-up
(issue 51).  These build and read the Arrow columnar format directly: a validity bitmap (bit i set:
value i present, least significant bit first), a values buffer (fixed width, or int32 offsets and
UTF-8 data for strings).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def _validity(present: np.ndarray) -> Any:
    import pyarrow as pa

    return pa.py_buffer(np.packbits(present, bitorder="little"))


def numbers(values: np.ndarray, mask: np.ndarray | None = None) -> Any:
    """A numeric Arrow array of ``values`` (float64, int64, int8...), null where ``mask`` is True."""
    import pyarrow as pa

    a = np.ascontiguousarray(values)
    null = None if mask is None or not mask.any() else mask
    return pa.Array.from_buffers(pa.from_numpy_dtype(a.dtype), len(a),
                                 [None if null is None else _validity(~null), pa.py_buffer(a)],
                                 null_count=0 if null is None else int(null.sum()))


def booleans(values: np.ndarray) -> Any:
    """An Arrow boolean array (bit-packed values) of ``values``."""
    import pyarrow as pa

    return pa.Array.from_buffers(pa.bool_(), len(values), [None, _validity(np.asarray(values, bool))], null_count=0)


def strings(values: Sequence[str | None]) -> Any:
    """An Arrow UTF-8 string array of ``values``, null where a value is None."""
    import pyarrow as pa

    encoded = [b"" if v is None else v.encode("utf-8") for v in values]
    offsets = np.zeros(len(encoded) + 1, np.int32)
    np.cumsum([len(b) for b in encoded], out=offsets[1:])
    null = np.array([v is None for v in values], bool)
    return pa.Array.from_buffers(pa.string(), len(encoded),
                                 [_validity(~null) if null.any() else None, pa.py_buffer(offsets),
                                  pa.py_buffer(b"".join(encoded))], null_count=int(null.sum()))


def to_numpy(col: Any) -> np.ndarray | None:
    """A fixed-width Arrow array without nulls as numpy (through ``to_tensor``: no copy, no pandas);
    None for any other array (the caller converts it its own way)."""
    import pyarrow as pa

    if col.null_count or not (pa.types.is_integer(col.type) or pa.types.is_floating(col.type)):
        return None
    if isinstance(col, pa.ChunkedArray):
        parts = [c.to_tensor().to_numpy() for c in col.chunks]
        return np.concatenate(parts) if parts else None
    return np.asarray(col.to_tensor().to_numpy())
