"""The one check every writing option of every command goes through: no output is an input or
a store the command can reach (docs/store.md, "No output replaces a store").

A command can reach up to three stores: its own (``--db``, ``--from-store``), its ``--config``'s
``store.path`` (the default station's when it has a ``--config`` option left out) and the default
store in the working directory (``accelcal-runs.sqlite``).  Each is an input of the identity check
(fileguard.identity), which ``--force`` never overrides: ``--force`` replaces a file of another
kind, or an SQLite database no store setting of the command names, never one of these.
"""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from ..fileguard.identity import Named, Output, refuse_overwrite
from ._common import config_store_file, store_file


def stores_reached(config: str | Path | None = None, has_config: bool = True,
                   own: Iterable[tuple[str, str | Path | None]] = ()) -> list[Named]:
    """Every store file a command can reach (module doc), labelled for the refusal line; ``own``:
    (option, store target) pairs, a server URL or None skipped; ``has_config`` False for a command
    without a --config option."""
    found: list[Named] = [(label, store_file(target)) for label, target in own]
    if has_config:
        label = f"the store of --config {config}" if config else "the default station's store"
        found.append((label, config_store_file(config)))
    from ..store.database import DEFAULT_STORE  # here: --help imports no store code

    found.append(("the default store", Path.cwd() / DEFAULT_STORE))
    return found


def refuse_output(outputs: Iterable[Output], inputs: Iterable[Named] = (), force: bool = False, *,
                  config: str | Path | None = None, has_config: bool = True,
                  stores: Iterable[tuple[str, str | Path | None]] = ()) -> None:
    """fileguard.identity.refuse_overwrite with every store the command reaches among the inputs
    (one line, exit 2, nothing written; ``--force`` included).  No output given: nothing to check (and
    no store or config code imported: `fit` without -o starts without them)."""
    outputs = list(outputs)
    if all(out[1] is None for out in outputs):
        return
    refuse_overwrite(outputs, [*inputs, *stores_reached(config, has_config, stores)], force)
