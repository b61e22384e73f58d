"""One validation of a mapping against a pydantic model, and the one line it gives on an error:
the key path, the value, what is allowed (ranges and choices read from the model; a discriminated
union's member found by its tag, kinds.TAGGED)."""
from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

from ..errors import ConfigError
from .kinds import CHOICES, TAGGED


def _models_in(ann: Any) -> list[type[BaseModel]]:
    """The section models inside a field's annotation (``X | None``, ``list[X]``, ...)."""
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return [ann]
    return [m for a in getattr(ann, "__args__", ()) for m in _models_in(a)]


def _model_at(model: type[BaseModel], loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The section model a validation error's location (without its last key) points into."""
    for part in loc:
        if isinstance(part, int):
            continue  # an item of a list of sections
        if part in TAGGED:  # a union's member, picked by its tag (driver=mma8451)
            model = TAGGED[part]
            continue
        if part not in model.model_fields:
            return None
        nested = _models_in(model.model_fields[part].annotation)
        if not nested:
            return None
        model = nested[0]
    return model


def _path(where: str, loc: tuple[Any, ...]) -> str:
    out = where
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _range(model: type[BaseModel] | None, key: Any) -> str:
    """``0 to 64``, ``above 0 to 60`` (exclusive lower bound), or '' when unbounded."""
    if model is None or key not in model.model_fields:
        return ""
    ge = gt = le = None
    for m in model.model_fields[key].metadata:
        ge = getattr(m, "ge", None) if getattr(m, "ge", None) is not None else ge
        gt = getattr(m, "gt", None) if getattr(m, "gt", None) is not None else gt
        le = getattr(m, "le", None) if getattr(m, "le", None) is not None else le
    if ge is None and gt is None and le is None:
        ge, gt, le = _bounds_in(model.model_fields[key].annotation)
    if ge is None and gt is None and le is None:
        return ""
    lo = _num(ge) if ge is not None else (f"above {_num(gt)}" if gt is not None else "-inf")
    return f"{lo} to {'inf' if le is None else _num(le)}"


def _bounds_in(ann: Any) -> tuple[Any, Any, Any]:
    """(ge, gt, le) of the numbers inside a list or union annotation (a per-axis [x, y, z])."""
    metas = [x for m in getattr(ann, "__metadata__", ()) for x in (m, *getattr(m, "metadata", ()))]
    found = {k: getattr(m, k) for m in metas for k in ("ge", "gt", "le") if getattr(m, k, None) is not None}
    if found:
        return found.get("ge"), found.get("gt"), found.get("le")
    for a in getattr(ann, "__args__", ()):
        inner = _bounds_in(a)
        if any(v is not None for v in inner):
            return inner
    return None, None, None


def _num(v: float) -> str:
    return str(v) if isinstance(v, int) else f"{v:g}"


def _choices(model: type[BaseModel] | None, key: Any) -> str:
    """A Literal field's allowed values, as people write them (``6, 9, 12, 15``)."""
    if model is None or key not in model.model_fields:
        return ""
    args = getattr(model.model_fields[key].annotation, "__args__", ())
    vals = [a for a in args if isinstance(a, (str, int))]
    return ", ".join(dict.fromkeys(str(v) for v in vals))


def error_line(err: ErrorDetails, root: type[BaseModel], where: str = "") -> str:
    """One line for a pydantic error: key path, value, what is allowed."""
    full = tuple(p for p in err["loc"] if isinstance(p, int) or p in TAGGED or not _is_tag(p))
    loc = tuple(p for p in full if isinstance(p, int) or p not in TAGGED)
    path, kind, value = _path(where, loc), err["type"], err.get("input")
    if kind.removesuffix("_choice") in CHOICES:  # a union's key (device.driver, jig.type) names no member
        tag, values = CHOICES[kind.removesuffix("_choice")]
        got = value.get(tag) if isinstance(value, dict) else value
        return f"{_path(where, (*loc, tag))}: {got!r}; allowed: {', '.join(values)}"
    # the key the error is about: the last name (a list item's error is about its list's key)
    k = max((i for i, p in enumerate(full) if not isinstance(p, int) and p not in TAGGED), default=None)
    parent = _model_at(root, full[:k]) if k is not None else root
    key = full[k] if k is not None else None
    if kind == "extra_forbidden":
        allowed = ", ".join(parent.model_fields) if parent is not None else ""
        return f"{path}: unknown key; allowed: {allowed}"
    if kind == "missing":
        return f"{path}: required"
    rng = _range(parent, key)
    if kind == "finite_number":
        return f"{path}: {value!r} is not a finite number; allowed: {rng or 'a finite number'}"
    if kind in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
        return f"{path}: {value!r} out of range; allowed: {rng}"
    if kind.startswith("int_") and isinstance(value, float) and not math.isfinite(value):
        return f"{path}: {value!r} is not a finite number; allowed: a whole number" + (f" {rng}" if rng else "")
    if kind.startswith("int_"):
        return f"{path}: {value!r}; allowed: a whole number" + (f" {rng}" if rng else "")
    if kind == "literal_error":
        expected = str(err.get("ctx", {}).get("expected", "")).replace(" or ", ", ")
        return f"{path}: {value!r}; allowed: {_choices(parent, key) or expected}"
    if kind in ("float_type", "float_parsing"):
        return f"{path}: {value!r} is not a number" + (f"; allowed: {rng}" if rng else "")
    if kind in ("model_type", "dict_type"):
        return f"{path}: {value!r}; allowed: a mapping"
    if kind == "bool_type":
        return f"{path}: {value!r}; allowed: true, false"
    if kind in ("list_type", "too_short", "too_long") and parent is not None and key in parent.model_fields:
        return f"{path}: {value!r}; allowed: a list ({parent.model_fields[key].description})"
    msg = err["msg"].removeprefix("Input should be ").removeprefix("Value error, ")  # a validator's own words
    return f"{path}: {value!r}; allowed: {msg}" + (f" ({rng})" if rng else "")


def _is_tag(part: str) -> bool:
    """pydantic's union-member tags in a location (``int``, ``list[...]``, ``function-...``)."""
    return part.startswith(("function-", "list[", "dict[", "literal[", "constrained-", "`")) \
        or part in ("int", "str", "float", "bool") \
        or part[:1].isupper()


def validate(data: Any, model: type[BaseModel], where: str = "") -> BaseModel:
    """``model`` checked from ``data``; the first error as one ConfigError line."""
    try:
        return model.model_validate(data)
    except ValidationError as e:
        # a union (``boards: 5`` or a list of mappings) reports every member's error: the one
        # reaching deepest into the data says what is wrong
        # (an unknown key before a missing one at the same depth: the typo is the likelier cause)
        # and a value of the wrong type for one member (a list for a number) says less than the other's
        errs = sorted(e.errors(), key=lambda x: (-len([p for p in x["loc"] if isinstance(p, int) or not _is_tag(p)]),
                                                 x["type"] != "extra_forbidden", x["type"].endswith("_type")))
        raise ConfigError(error_line(errs[0], model, where)) from None
