"""docs/config.md from the declared schema: ``python -m accelcal_station.config.docs > docs/config.md``.

A test compares the committed file with this output, so the key reference cannot drift
from what the station accepts."""
from __future__ import annotations

import sys
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from .schema import TAGGED, StationConfigSchema, _models_in, _range

HEADER = """# Station configuration keys

Generated from `accelcal_station/config/schema.py` by
`python -m accelcal_station.config.docs > docs/config.md`; do not edit by hand.

A station config (`accelcal run --config F`, configs/*.yaml) is a YAML mapping of the
sections below. Every key is checked before anything touches a board: an unknown key,
a wrong type, a number that is not finite or out of its range gives one line naming the
key path, the value and what is allowed, and exit 2.  The file is read once and validated
once into these models; the station, its factories and flows then read the typed sections,
never the file's mapping again (docs/architecture.md, "One typed configuration"), and a run
records the very text that was parsed.

`device`, `jig` and `chamber` are discriminated unions: `device.driver` (simulated, mma8451,
mpu6050), `jig.type` (simulated, operator, motorized) and `chamber.type` (visa, emulated) pick
one model, whose table (`device (driver: mma8451)`, `jig (type: motorized)`,
`chamber (type: emulated)`, ...) lists the keys that driver or type accepts, with its own
defaults and ranges: a key of another driver is refused in one line naming this driver's keys.
A chamber without `type` is a real one (visa), unless it has the older `port: emulated`, which
still means the emulated chamber.
"""


def _type(ann: Any) -> str:
    """The type in the YAML reader's words (``float``, ``list of 3 float``, ``'normal' / 'low_power'``,
    ``section``), never a Python repr; ``|`` escaped for the table."""
    tags: dict[type[BaseModel], str] = {m: t for t, m in TAGGED.items()}
    members = [m for m in _models_in(ann) if m in tags]
    if members:  # a discriminated union: its members' tables follow ("device (driver: mma8451)")
        key = tags[members[0]].split("=")[0]
        opt = " \\| null" if type(None) in get_args(ann) else ""
        return f"one of {len(members)} by `{key}`{opt}"
    return _name(ann).replace("|", "\\|")


def _name(ann: Any) -> str:
    origin, args = get_origin(ann), get_args(ann)
    if ann is type(None):
        return "null"
    if origin is Annotated:  # constraints: a list's length here; numbers' bounds go to the range column
        lengths = {getattr(m, k) for m in _metadata(args[1:]) for k in ("min_length", "max_length")
                   if getattr(m, k, None) is not None}
        inner = _name(args[0])
        return f"list of {lengths.pop()} {inner.removeprefix('list of ')}" if len(lengths) == 1 and \
            inner.startswith("list of ") else inner
    if origin in (Union, UnionType):
        return " | ".join(dict.fromkeys(_name(a) for a in args))
    if origin is Literal:
        return " / ".join(_literal(a) for a in args)
    if origin is list:
        return f"list of {_grouped(_name(args[0]))}"
    if origin is dict:
        return f"mapping of {_name(args[0])} to {_grouped(_name(args[1]))}"
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return "section"
    return _NAMES.get(getattr(ann, "__name__", ""), getattr(ann, "__name__", str(ann)))


_NAMES = {"JsonValue": "JSON value", "NoneType": "null"}


def _metadata(metas: tuple[Any, ...]) -> list[Any]:
    """Constraint objects, unwrapped from pydantic's FieldInfo."""
    return [x for m in metas for x in (m, *getattr(m, "metadata", ()))]


def _grouped(name: str) -> str:
    return f"({name})" if " | " in name or " / " in name else name


def _literal(v: object) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    return f"'{v}'" if isinstance(v, str) else str(v)


def _hex(field: Any) -> bool:
    extra = field.json_schema_extra
    return isinstance(extra, dict) and extra.get("notation") == "hex"


def _default(field: Any) -> str:
    d = field.default
    if d is PydanticUndefined:
        return "required"
    if d is None:
        return "-"
    if _hex(field) and isinstance(d, int):
        return f"`0x{d:02x}`"
    return f"`{str(d).lower() if isinstance(d, bool) else d}`"


def _shown_range(model: type[BaseModel], name: str) -> str:
    """The allowed range; in hex for a number written in hex (an I2C address: 0x00 to 0x7f)."""
    field = model.model_fields[name]
    if _hex(field):
        bounds = {k: getattr(m, k) for m in _metadata(tuple(field.metadata)) for k in ("ge", "le")
                  if getattr(m, k, None) is not None}
        if len(bounds) == 2:
            return f"0x{bounds['ge']:02x} to 0x{bounds['le']:02x}"
    return _range(model, name) or "-"


def section_rows(model: type[BaseModel], path: str, variant: str = "") -> list[tuple[str, type[BaseModel]]]:
    """(key path, model) of ``model`` and every section nested in it, depth first; a union's
    members titled by their tag (``device (driver: mma8451)``, ``device.eeprom (driver: mma8451)``)."""
    tags: dict[type[BaseModel], str] = {m: t for t, m in TAGGED.items()}
    out = [(path + variant, model)]
    for name, field in model.model_fields.items():
        for sub in dict.fromkeys(_models_in(field.annotation)):
            if issubclass(model, sub):  # a panel's boards: the panel's own keys again
                continue
            sub_variant = " ({}: {})".format(*tags[sub].split("=")) if sub in tags else variant
            out += section_rows(sub, f"{path}.{name}" if path else name, sub_variant)
    return out


def keys(model: type[BaseModel] = StationConfigSchema, path: str = "") -> list[str]:
    """Every key path the schema accepts (``capture.block_s``, ``device.eeprom.size_bytes``, ...)."""
    return list(dict.fromkeys(f"{p.split(' (')[0]}.{k}" if p else k
                              for p, m in section_rows(model, path) for k in m.model_fields))


def render() -> str:
    """The whole reference, one table per section."""
    parts = [HEADER]
    for path, model in section_rows(StationConfigSchema, ""):
        title = path or "top level"
        doc = (model.__doc__ or "").strip().splitlines()[0] if model.__doc__ and path else ""
        parts.append(f"\n## `{title}`\n" + (f"\n{doc}\n" if doc else ""))
        parts.append("\n| key | type | default | allowed range | meaning |\n|---|---|---|---|---|")
        for name, field in model.model_fields.items():
            rng = _shown_range(model, name)
            parts.append(f"| `{name}` | {_type(field.annotation)} | {_default(field)} | {rng} | "
                         f"{(field.description or '').replace('|', '/')} |")
    return "\n".join(parts) + "\n"


if __name__ == "__main__":  # pragma: no cover - the command line form of render()
    sys.stdout.write(render())
