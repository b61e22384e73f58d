"""`accelcal report certificate` and `report verify-certificate`: a board's calibration certificate from
the store, and the check of one against it (docs/certificate.md)."""
from __future__ import annotations

import json
import os
import re
import stat
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import click

from .. import __version__
from ..errors import DataError
from ..jsontypes import JsonObject
from ..store.reader import StoreReader
from ._common import MAX_ID, Whole, force_option
from ._report_filters import open_reader
from ._text import clean

if TYPE_CHECKING:
    from ..lot.certificate_html import Certified

CHUNK = 500  # run ids per query
MAX_FILE_BYTES = 256 * 2**20  # ~25 kB a board: a lot of 10,000 boards fits; a larger file is no certificate

_store_options = [
    click.option("--db", "--store", "db", default=None, metavar="FILE|URL",
                 help="Results store: an SQLite file, sqlite:///FILE or postgresql://USER@HOST/DB; default: the "
                      "store of --config or of the default station."),
    click.option("--config", "config_path", default=None, metavar="FILE", help="Station config (store.path)."),
    click.option("--json", "as_json", is_flag=True, help="Print JSON."),
]


def _default_name(run_id: int | None, lot: str | None) -> str:
    if lot is not None:
        return f"certificate-lot-{re.sub(r'[^A-Za-z0-9._-]', '_', lot)[:80]}.html"
    return f"certificate-run-{run_id}.html"


def _lot_certificates(store: StoreReader, lot: str) -> tuple[list[Certified], list[str]]:
    """Every board of lot ``lot``: its newest complete run's certified content; the boards left out, named."""
    from ..lot.certificate import certified, content_hash, lot_choice, refusal
    from ..lot.certificate_html import Certified

    listing = store.list_runs(lot=lot)
    if not listing:
        raise DataError(f"--lot {lot!r}: no runs of that lot in {store.path}")
    ids, left = lot_choice(listing)
    recs = [r for k in range(0, len(ids), CHUNK) for r in store.runs(run_ids=ids[k:k + CHUNK])]
    certs: list[Certified] = []
    for rec in recs:
        if (why := refusal(rec)) is not None:
            left.append(f"{rec.device_serial}: {why}")
            continue
        content = certified(rec)
        certs.append(Certified(content, content_hash(content)))
    if not certs:
        raise DataError(f"--lot {lot!r}: no board of the lot can be certified ({left[0]})")
    return certs, left


@click.command("certificate")
@click.argument("run_id", required=False, type=Whole(1, MAX_ID))
@click.option("--lot", default=None, metavar="LOT", help="Every board of this lot (its newest complete run each), "
              "one printed page per board, in one file.")
@click.option("-o", "--output", default=None, metavar="FILE.html",
              help="Write here, atomically (default certificate-run-RUN.html or certificate-lot-LOT.html).")
@_store_options[0]
@_store_options[1]
@_store_options[2]
@force_option
def certificate_command(run_id: int | None, lot: str | None, output: str | None, db: str | None,
                        config_path: str | None, as_json: bool, force: bool = False) -> None:
    """A printable calibration certificate of one board's run (or of every board of a lot), with the content's
    SHA-256. A station fault or a run without a calibration gets none (exit 2)."""
    from ..atomic import atomic_write
    from ..lot.certificate import certified, content_hash
    from ..lot.certificate_html import Certified, document

    if (run_id is None) == (lot is None):
        raise DataError("give a RUN id or --lot LOT (one of them)")
    out = output or _default_name(run_id, lot)
    left: list[str] = []
    with open_reader(db, config_path, ("-o", out, "html"), force) as store:
        if lot is not None:
            certs, left = _lot_certificates(store, lot)
        else:
            assert run_id is not None
            content = certified(store.get_run(run_id))
            certs = [Certified(content, content_hash(content))]
    chosen = certs
    issued = f"{datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')} by accelcal {__version__}"
    title = f"Calibration certificate, lot {lot}" if lot is not None else f"Calibration certificate, run {run_id}"
    atomic_write(out, document(chosen, title, issued))
    for line in left:
        click.echo(clean(f"SKIP {line}"), err=True)
    if as_json:
        click.echo(json.dumps({"path": out, "runs": [c.content["run"] for c in chosen],
                               "sha256": [c.sha256 for c in chosen], "skipped": left}))
    else:
        click.echo(clean(f"certificate of {len(chosen)} board(s) written to {out}"
                         + (f" (run {run_id}, SHA-256 {chosen[0].sha256})" if lot is None else
                            f" (lot {lot}; {len(left)} board(s) left out)")))


def _read(path: str) -> str:
    """The certificate file's text: a regular file of sane size, UTF-8 (one line otherwise)."""
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise DataError(f"{path}: not a regular file; a certificate (.html) is allowed")
        if st.st_size > MAX_FILE_BYTES:
            raise DataError(f"{path}: {st.st_size} bytes; a certificate file is at most {MAX_FILE_BYTES}")
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not UTF-8 text; a certificate written by `accelcal report certificate` is") from None
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None


@click.command("verify-certificate")
@click.argument("file", metavar="FILE")
@_store_options[0]
@_store_options[1]
@_store_options[2]
@click.pass_context
def verify_certificate_command(ctx: click.Context, file: str, db: str | None, config_path: str | None,
                               as_json: bool) -> None:
    """Check a certificate against the store's current content of the runs it names: exit 0 "verified", 1 when
    the file was edited or the store differs (the field named)."""
    from ..lot.certificate import certified
    from ..lot.certificate_verify import verify

    text = _read(file)
    with open_reader(db, config_path) as store:

        def stored(rid: int) -> JsonObject:
            return certified(store.get_run(rid))

        try:
            res = verify(text, stored)
        except DataError as e:
            raise DataError(f"{file}: {e}") from None
    headline = (f"verified: {file}: {len(res.runs)} board(s) (run{'s' if len(res.runs) > 1 else ''} "
                f"{', '.join(map(str, res.runs))}) match the store" if res.ok else
                f"NOT VERIFIED: {file}: {res.mismatches[0].line()}"
                + (f" (+{len(res.mismatches) - 1} more; --json lists them)" if len(res.mismatches) > 1 else ""))
    if as_json:
        click.echo(json.dumps({"file": file, "verified": res.ok, "runs": res.runs, "message": headline,
                               "mismatches": [m.to_json() for m in res.mismatches]}))
    else:
        click.echo(clean(headline))
    if not res.ok:
        ctx.exit(1)
