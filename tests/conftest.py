from __future__ import annotations

from pathlib import Path

import pytest
import yaml

# Everything the tests read lives in the repository (tests/data/README.md gives each
# file's provenance and licence), so a plain clone passes with nothing beside it.
DATA = Path(__file__).resolve().parent / "data"
REPO = DATA.parents[1]


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return DATA


@pytest.fixture(scope="session")
def an4399() -> dict:
    return yaml.safe_load((DATA / "an4399.yaml").read_text())


@pytest.fixture(scope="session")
def calibraxis() -> dict:
    return yaml.safe_load((DATA / "calibraxis_points.yaml").read_text())


@pytest.fixture(scope="session")
def nine_position_paper() -> dict:
    return yaml.safe_load((DATA / "nine_position_paper.yaml").read_text())


@pytest.fixture(scope="session")
def pg_server():
    """A throwaway PostgreSQL server (tests/pgserver.py); skipped with the reason where unavailable."""
    from pgserver import PgServer

    server = PgServer()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request, tmp_path):
    """A fresh results store as a URL: an SQLite file, and a database on the throwaway server."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'line.sqlite'}"
    return request.getfixturevalue("pg_server").new_database()
