from __future__ import annotations

from pathlib import Path

import pytest
import yaml

SHARED = Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture(scope="session")
def shared() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"../shared not found at {SHARED}: tests need the shared vectors and datasets")
    return SHARED


@pytest.fixture(scope="session")
def an4399(shared) -> dict:
    return yaml.safe_load((shared / "vectors" / "an4399.yaml").read_text())


@pytest.fixture(scope="session")
def calibraxis(shared) -> dict:
    return yaml.safe_load((shared / "datasets" / "calibraxis_points.yaml").read_text())


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
