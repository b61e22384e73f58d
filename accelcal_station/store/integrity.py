"""What is damaged in a store, row by row and page by page; nothing is written.

``check_rows``: every value of every row through rowcheck.check_row, one read transaction per
table so a damaged page ends only its own table's read (named as the rows it could not read on
from).  ``file_problems``: SQLite's ``PRAGMA integrity_check`` (pages it cannot read, broken
b-trees, indexes out of step; at most 100 lines); when a page is too broken for the whole check,
each table with its indexes is checked alone and named with the root pages of its b-trees.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from .rowcheck import DamagedRow, check_row

if TYPE_CHECKING:
    from sqlalchemy import Table

    from .database import Database

_TREES = ("SELECT t.type, t.name, t.rootpage || coalesce(', its indexes at pages ' || (SELECT group_concat("
          "i.rootpage, ', ') FROM sqlite_master i WHERE i.type = 'index' AND i.tbl_name = t.name), '') "
          "FROM sqlite_master t WHERE t.type = 'table' AND t.rootpage > 0 ORDER BY t.rootpage")


def _first_line(e: BaseException) -> str:
    """The driver's own first line of a database error (SQLAlchemy wraps it in a long text)."""
    orig = getattr(e, "orig", None)
    return (str(orig if orig is not None else e).strip().splitlines() or [type(e).__name__])[0]


def check_rows(db: Database, tables: Iterable[Table]) -> list[DamagedRow]:
    """Every damaged value of every row of ``tables``; a table not readable to its end is one DamagedRow
    (column ``*``) saying after which row its read stopped."""
    from sqlalchemy import select
    from sqlalchemy.exc import SQLAlchemyError

    found: list[DamagedRow] = []
    for table in tables:
        n = 0
        try:
            db.begin(write=False)
            for row in db.execute(select(table)).mappings():
                found += check_row(table.name, dict(row)).damage
                n += 1
        except SQLAlchemyError as e:
            found.append(DamagedRow(table.name, f"after row {n}", "*", f"cannot read on ({_first_line(e)})"))
        finally:
            db.rollback()  # nothing was written: a rollback never fails where a commit could
    return found


def file_problems(db: Database) -> list[str]:
    """What SQLite's integrity check finds wrong in the file (module doc); [] when it is sound."""
    from sqlalchemy.exc import SQLAlchemyError

    try:
        got = [str(r[0]) for r in db.conn.exec_driver_sql("PRAGMA integrity_check(100)")]
    except SQLAlchemyError:  # a page too broken for the whole check: each table checked on its own
        return _per_table(db)
    return [] if got == ["ok"] else [ln for g in got for ln in g.splitlines() if ln.strip()]


def _per_table(db: Database) -> list[str]:
    """Each table (with its indexes) checked alone, named with its b-trees' root pages."""
    from sqlalchemy.exc import SQLAlchemyError

    try:
        trees = [(str(r[0]), str(r[1]), r[2]) for r in db.conn.exec_driver_sql(_TREES)]
    except SQLAlchemyError as e:
        return [f"the schema (page 1) cannot be read ({_first_line(e)})"]
    out: list[str] = []
    for kind, name, root in trees:
        quoted = '"' + name.replace('"', '""') + '"'
        try:
            got = [str(r[0]) for r in db.conn.exec_driver_sql(f"PRAGMA integrity_check({quoted})")]
        except SQLAlchemyError as e:
            out.append(f"{kind} {name} (b-tree at page {root}): cannot be read ({_first_line(e)})")
            continue
        out += [] if got == ["ok"] else [f"{kind} {name} (b-tree at page {root}): {g}" for g in got]
    return out
