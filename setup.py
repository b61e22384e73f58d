"""The package list, the one thing pyproject.toml cannot say: accelcal_station's own subpackages found
on disk plus the top-level folders [tool.setuptools.package-dir] maps into it (drivers/, fixtures/,
configs/ install as accelcal_station.drivers, ...). Everything else is in pyproject.toml."""
import tomllib
from pathlib import Path

from setuptools import find_packages, setup

HERE = Path(__file__).resolve().parent
MAPPED: dict[str, str] = tomllib.loads((HERE / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]

setup(packages=[*find_packages(where=str(HERE), include=["accelcal_station", "accelcal_station.*"]),
                *(f"{name}{sub}" for name, folder in MAPPED.items()
                  for sub in ["", *(f".{p}" for p in find_packages(where=str(HERE / folder)))])])
