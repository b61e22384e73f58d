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
