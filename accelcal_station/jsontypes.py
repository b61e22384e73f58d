"""JSON values as types: what `json.dumps` accepts, with no `Any` in it.

`JsonObject` is for documents whose keys are open (a `--json` object assembled from parts, a
stored JSON column read back); records whose keys are known are TypedDicts or dataclasses.
Unlike `dict[str, Any]`, mypy rejects an ndarray or a datetime put into one, which `json.dumps`
would refuse at run time.  Functions that only read a document take `Mapping[str, JsonValue]`
(dicts are invariant: a `dict[str, float]` is not a `dict[str, JsonValue]`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeAlias

JsonScalar: TypeAlias = str | int | float | bool | None
JsonValue: TypeAlias = "JsonScalar | list[JsonValue] | dict[str, JsonValue]"
JsonObject: TypeAlias = "dict[str, JsonValue]"
JsonReadable: TypeAlias = "JsonScalar | Sequence[JsonReadable] | Mapping[str, JsonReadable]"
