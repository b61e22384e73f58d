"""The declared station-config schema: docs/config.md generated from it, every key the code
reads declared in it, one line for an unknown key in any section or a number out of range."""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
import yaml
from click.testing import CliRunner
from pydantic import BaseModel

from accelcal_station.acceptance.rules import LIMIT_KEYS
from accelcal_station.cli import cli
from accelcal_station.config.docs import keys, render, section_rows
from accelcal_station.config.schema import StationConfigSchema, validate_station
from accelcal_station.config.sections import default_config_path
from accelcal_station.drivers.mma8451_settings import Mma8451Settings
from accelcal_station.drivers.mpu6050_settings import Mpu6050Settings
from accelcal_station.fixtures.motorized_jig import JigAxes, JigLink
from accelcal_station.fixtures.simulated_hand import SimulatedHand
from accelcal_station.station.capture import CaptureSettings
from accelcal_station.station.identity import IDENTITY_KEYS
from accelcal_station.station.thermal_plan import SoakRule, ThermalPlan

REPO = Path(__file__).resolve().parents[1]


def test_docs_config_md_is_generated_from_the_schema() -> None:
    assert (REPO / "docs" / "config.md").read_text() == render(), \
        "regenerate: python -m accelcal_station.config.docs > docs/config.md"


def _params(init: Any, *skip: str) -> tuple[str, ...]:
    """A constructor's keyword names (what it takes from its config section)."""
    import inspect
    return tuple(n for n in inspect.signature(init).parameters if n not in ("self", *skip))


def _sections_read() -> tuple[str, ...]:
    """Every top-level section the package reads from a station config (``cfg.schema.x``)."""
    import re
    found = {m for f in (REPO / "accelcal_station").rglob("*.py")
             for m in re.findall(r"\b(?:cfg|config|self)\.schema\.(\w+)\b", f.read_text())} - set(dir(BaseModel))
    assert {"device", "jig", "thermal", "chamber"} <= found, found  # the scan itself works
    return tuple(sorted(found))


def test_no_module_reads_a_raw_station_config_mapping() -> None:
    """The config is validated once into the schema's models (StationConfig.schema): no module
    reads sections back from the file's mapping (``.raw[...]``, ``cfg.raw``), and StationConfig
    has no such mapping to read."""
    import re

    from accelcal_station.station.settings import StationConfig
    assert "raw" not in StationConfig.__dataclass_fields__
    pattern = re.compile(r"\.raw\[|\b(?:cfg|config|self\.cfg)\.raw\b")
    readers = [f"{f.relative_to(REPO)}:{i}" for f in sorted((REPO / "accelcal_station").rglob("*.py"))
               for i, line in enumerate(f.read_text().splitlines(), 1) if pattern.search(line)]
    assert not readers, readers


def test_the_config_text_recorded_is_the_text_parsed(tmp_path: Path) -> None:
    """A run records the very bytes its configuration was parsed from (read once): the file
    replaced after loading does not change what is recorded."""
    from accelcal_station.station.settings import StationConfig
    p = tmp_path / "station.yaml"
    text = default_config_path().read_text() + "\n# this very text\n"
    p.write_text(text)
    cfg = StationConfig.load(p)
    p.write_text("device: {driver: simulated}\n")
    assert cfg.text == text
    assert cfg.device.driver == "simulated" and cfg.schema.plan is not None


def test_schema_defaults_are_the_settings_defaults() -> None:
    from accelcal_station.config.schema import CaptureSection, SoakSection
    assert CaptureSection().model_dump() == CaptureSettings().__dict__
    assert SoakSection().model_dump() == SoakRule().__dict__


def test_every_key_the_code_reads_is_in_the_schema() -> None:
    # the key lists the sections' own code checks against (drivers, jigs, station, chamber)
    code: dict[str, tuple[str, ...]] = {
        "": _sections_read(), "acceptance": tuple(LIMIT_KEYS), "capture": tuple(CaptureSettings.__dataclass_fields__),
        "station": ("id", *IDENTITY_KEYS), "thermal": tuple(ThermalPlan.__dataclass_fields__),
        "thermal.soak": tuple(SoakRule.__dataclass_fields__),
        # the keywords the drivers and jigs take from their typed sections (declared apart from the schema)
        "device": tuple(Mma8451Settings.__annotations__) + tuple(Mpu6050Settings.__annotations__)
        + ("driver", "boards", "spread", "mux", "bus", "port"),
        "jig": ("port", *JigLink.__dataclass_fields__, *JigAxes.__dataclass_fields__, "type", "move_time_s",
                "rated_speed_dps", "settle_s", "hand"),
        "jig.hand": _params(SimulatedHand.__init__, "board"),
        "plan": ("design", "model"), "nvm": ("write", "slot_size", "offset_trim"),
        "verify": ("poses", "design", "mode"),
        "store": ("path",),
    }
    declared = set(keys())
    missing = [f"{s}.{k}" if s else k for s, ks in code.items() for k in ks if (f"{s}.{k}" if s else k) not in declared]
    assert not missing, missing
    doc = (REPO / "docs" / "config.md").read_text()
    for path, model in section_rows(StationConfigSchema, ""):
        assert f"## `{path or 'top level'}`" in doc
        assert all(f"| `{k}` |" in doc for k in model.model_fields)


def _leaves(d: Any, path: str = "") -> list[str]:
    if not isinstance(d, dict):
        return [path.rstrip(".")]
    return [p for k, v in d.items() for p in ([path + k] if k == "effects" else _leaves(v, f"{path}{k}."))]


@pytest.mark.parametrize("config", sorted((REPO / "configs").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_configs_validate_and_use_declared_keys(config: Path) -> None:
    raw = yaml.safe_load(config.read_text())
    validate_station(raw)
    declared = set(keys())
    # an emulated mpu6050's device.simulator is a board mapping: the device keys again
    undeclared = [p for p in _leaves(raw) if p not in declared and p.replace("device.simulator.", "device.")
                  not in declared]
    assert not undeclared, undeclared


def _put(cfg: dict, path: str, key: str, value: Any) -> None:
    node = cfg
    for part in [p for p in path.split(".") if p]:
        nxt = node.get(part)
        if not isinstance(nxt, dict):
            nxt = {} if part != "boards" else {}
            node[part] = nxt
        node = nxt
    node[key] = value


def _write(tmp_path: Path, cfg: dict) -> str:
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return str(p)


def _one_line(r: Any) -> str:
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


# the sections the default config (sim.yaml: a simulated device, a simulated jig) reaches; the
# union members of other drivers and jig types are reached in the test below
SECTIONS = [p for p, _ in section_rows(StationConfigSchema, "")
            if ".boards" not in p and (" (" not in p or p.endswith(("(driver: simulated)", "(type: simulated)")))]


@pytest.mark.parametrize("section", SECTIONS, ids=lambda s: s or "top")
def test_an_unknown_key_in_any_section_is_one_line_naming_the_allowed_keys(tmp_path: Path, section: str) -> None:
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    path = section.split(" (")[0]  # "device (driver: simulated)": the key path "device"
    _put(cfg, path, "bogus_key", 1)
    r = CliRunner().invoke(cli, ["run", "--config", _write(tmp_path, cfg)])
    line = _one_line(r)
    model = dict(section_rows(StationConfigSchema, ""))[section]
    where = f"{path}.bogus_key" if path else "bogus_key"
    assert line.startswith(f"error: {where}: unknown key; allowed: "), line
    assert line.endswith(", ".join(model.model_fields)), line


@pytest.mark.parametrize(("section", "key", "text", "shown"), [
    ("capture", "block_s", "1.0e+300", "1e+300"),
    ("capture", "target_sem_mg", "1e300", "'1e300'"),  # YAML 1.1: no dot, a string
    ("device", "odr_hz", str(2**64), str(2**64)),
    ("acceptance", "residual_rms_mg", "1.0e+300", "1e+300"),
    ("device.eeprom", "size_bytes", str(2**64), str(2**64)),
])
def test_huge_config_numbers_are_one_line(tmp_path: Path, section: str, key: str, text: str, shown: str) -> None:
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    _put(cfg, section, key, "@@")
    p = _write(tmp_path, cfg)
    Path(p).write_text(Path(p).read_text().replace("'@@'", text))
    r = CliRunner().invoke(cli, ["run", "--config", p])
    line = _one_line(r)
    assert line.startswith(f"error: {section}.{key}: {shown}"), line
    assert "allowed:" in line and " to " in line, line
    # under --json the same line is one JSON object on stdout
    rj = CliRunner().invoke(cli, ["run", "--config", p, "--json"])
    assert rj.exit_code == 2
    assert json.loads(rj.stdout)["error"] == line.removeprefix("error: ")


def test_a_chamber_without_pyvisa_is_one_line_naming_the_extra(tmp_path: Path) -> None:
    """pyvisa is the optional ``chamber`` extra: a thermal plan without it is refused before any
    emulator or port opens (pyvisa hidden from a real interpreter by a None sys.modules entry)."""
    import subprocess
    import sys
    code = ("import sys; sys.modules['pyvisa'] = None; sys.modules['pyvisa_py'] = None\n"
            "from accelcal_station.cli import main\n"
            f"sys.argv = ['accelcal', 'run', '--config', {str(REPO / 'configs' / 'thermal-sim.yaml')!r}]\n"
            "main()\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "pyvisa" in lines[0] and "accelcal-station[chamber]" in lines[0], lines[0]


def test_paths_named_in_the_shipped_configs_exist() -> None:
    import re
    for config in sorted((REPO / "configs").glob("*.yaml")):
        for name in re.findall(r"[\w./-]+/[\w.-]+\.(?:md|py)\b", config.read_text()):
            assert (REPO / name).exists(), f"{config.name} names {name}, which is not in the repository"


@pytest.mark.parametrize(("section", "patch", "where", "model"), [
    ("device", {"driver": "simulated", "bus": 1}, "device.bus", "device (driver: simulated)"),
    ("device", {"driver": "mma8451", "dlpf": 3}, "device.dlpf", "device (driver: mma8451)"),
    ("device", {"driver": "mpu6050", "port": "emulated", "oversampling": "normal"}, "device.oversampling",
     "device (driver: mpu6050)"),
    ("jig", {"type": "operator", "port": "/dev/ttyUSB0"}, "jig.port", "jig (type: operator)"),
    ("jig", {"type": "simulated", "tolerance_deg": 5}, "jig.tolerance_deg", "jig (type: simulated)"),
    ("device", {"driver": "mpu6050", "port": "emulated", "mux": {"address": 0x70}}, "device.mux",
     "device (driver: mpu6050)"),
])
def test_a_key_of_another_driver_or_jig_type_is_one_line_naming_this_ones_keys(
        tmp_path: Path, section: str, patch: dict, where: str, model: str) -> None:
    """The per-driver and per-jig-type key sets (the discriminated unions of config/schema.py)
    are checked in the one validation when the config is loaded, before any board or port is
    opened; docs/config.md lists each of them."""
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg[section] = {**({} if section == "jig" else cfg[section]), **patch}
    if section == "device":  # keys the simulated board has and the others do not
        for k in ("simulator", "effects", "chip", "realtime", "ambient_c", "self_heating_c", "eeprom"):
            if patch["driver"] != "simulated":
                cfg[section].pop(k, None)
    line = _one_line(CliRunner().invoke(cli, ["run", "--config", _write(tmp_path, cfg)]))
    fields = dict(section_rows(StationConfigSchema, ""))[model].model_fields
    allowed = ", ".join(fields)
    assert line == f"error: {where}: unknown key; allowed: {allowed}", line
    assert where.split(".")[-1] not in fields  # the key is another driver's or jig type's
    assert f"## `{model}`" in (REPO / "docs" / "config.md").read_text()


@pytest.mark.parametrize(("section", "value", "line"), [
    ("device", {"driver": "mma8452"}, "device.driver: 'mma8452'; allowed: simulated, mma8451, mpu6050"),
    ("device", {"driver": 5}, "device.driver: 5; allowed: simulated, mma8451, mpu6050"),
    ("device", [1, 2], "device: [1, 2]; allowed: a mapping"),
    ("jig", {"type": "robot"}, "jig.type: 'robot'; allowed: simulated, operator, motorized"),
    ("device", {"driver": "simulated", "boards": [{"driver": "mpu6050"}]},
     "device.boards[0].driver: 'mpu6050'; allowed: simulated"),
    ("device", {"driver": "mma8451", "bus": "emulated", "simulator": {"chip": "mma8451", "bogus": 1}},
     "device.simulator.bogus: unknown key; allowed: chip, range_g, odr_hz, dlpf, seed, serial, realtime, "
     "ambient_c, self_heating_c, eeprom, simulator, effects, true_mount"),
])
def test_a_bad_driver_or_jig_type_is_one_line_naming_the_allowed_ones(
        tmp_path: Path, section: str, value: Any, line: str) -> None:
    """The discriminating key itself (device.driver, jig.type), a panel board of another driver and
    an emulated board's own keys: each one line from the one validation."""
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg[section] = value
    assert _one_line(CliRunner().invoke(cli, ["run", "--config", _write(tmp_path, cfg)])) == f"error: {line}"


@pytest.mark.parametrize(("chamber", "line"), [
    ({"type": "oven"}, "chamber.type: 'oven'; allowed: visa, emulated"),
    ({"type": "visa"}, "chamber.port: required"),
    ({"port": "/dev/ttyUSB2", "emulator": {"start_c": 20}}, "chamber.emulator: unknown key; allowed: type, driver, "
     "timeout_s, retries, min_c, max_c, port, baud, visa_library"),
    ({"type": "emulated", "visa_library": "@ivi"}, "chamber.visa_library: unknown key; allowed: type, driver, "
     "timeout_s, retries, min_c, max_c, emulator, port"),
    ({"port": "emulated", "baud": 9600}, "chamber.baud: unknown key; allowed: type, driver, timeout_s, retries, "
     "min_c, max_c, emulator, port"),
])
def test_a_bad_chamber_is_one_line_naming_its_types_keys(tmp_path: Path, chamber: dict, line: str) -> None:
    """chamber.type picks a real chamber (visa: port, baud, VISA backend) or the emulated one (its
    physics and faults); each type's keys are checked in the one validation when the config loads."""
    cfg = yaml.safe_load((REPO / "configs" / "thermal-sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["chamber"] = chamber
    assert _one_line(CliRunner().invoke(cli, ["run", "--config", _write(tmp_path, cfg)])) == f"error: {line}"


def test_the_older_chamber_spelling_still_means_the_emulated_chamber(tmp_path: Path) -> None:
    """``port: emulated`` without a type (configs written before chamber.type) is the emulated chamber:
    it starts around the simulated board and answers; ``type: visa`` with that port is refused in one line
    whose hint (chamber.type: emulated) is the spelling the shipped configs use."""
    from accelcal_station.config.schema import EmulatedChamberConfig, validate_chamber, validate_device
    from accelcal_station.drivers.factory import make_driver
    from accelcal_station.errors import ConfigError
    from accelcal_station.fixtures.factory import board_of
    from accelcal_station.instruments.factory import make_chamber

    old = validate_chamber({"port": "emulated", "emulator": {"start_c": 31.0}})
    new = validate_chamber({"type": "emulated", "emulator": {"start_c": 31.0}})
    assert isinstance(old, EmulatedChamberConfig) and isinstance(new, EmulatedChamberConfig)
    board = board_of(make_driver(validate_device({"driver": "simulated", "seed": 1})))
    for section in (old, new):
        with make_chamber(section, board) as ch:
            assert ch.status().air_c == pytest.approx(31.0, abs=0.1)
    with pytest.raises(ConfigError) as e:
        make_chamber(validate_chamber({"type": "visa", "port": "emulated"}))
    assert str(e.value) == ("chamber.port: 'emulated'; allowed: a serial device path (/dev/ttyUSB2, COM3), "
                            "host:port or a VISA resource name (the emulated chamber: chamber.type: emulated)")
    shipped = yaml.safe_load((REPO / "configs" / "thermal-sim.yaml").read_text())["chamber"]
    assert shipped["type"] == "emulated" and "port" not in shipped


def test_the_factories_drivers_jigs_and_chamber_validate_nothing_again() -> None:
    """One validation path: a station config is validated once (config/schema.py), a command's or a test's
    mapping through validate_device/validate_jig/validate_chamber; the factories, drivers, jigs, chamber and
    panel merge take the typed models and call no validation of their own.  Only what reads another input
    validates it: a simulator or board file (drivers/simulated_section.py, drivers/emulator_files.py) and a board
    mapping handed to SimulatedBoard.from_config."""
    import ast
    names = {"parse", "validate", "validate_device", "validate_jig", "validate_chamber", "model_validate"}
    allowed = {("simulated_section.py", "simulator_of"), ("simulated.py", "from_config"),
               ("emulator_files.py", "emulator_options_from_file"), ("emulator_files.py", "board_config_from_file")}
    pkg = REPO / "accelcal_station"
    # drivers/ and fixtures/ sit at the top of the repository (installed as accelcal_station.drivers, ...)
    files = [*(REPO / "drivers").glob("*.py"), *(REPO / "fixtures").glob("*.py"), *(pkg / "instruments").glob("*.py"),
             pkg / "station" / "panel_config.py"]
    found = []
    for f in files:
        for fn in ast.walk(ast.parse(f.read_text())):
            if not isinstance(fn, ast.FunctionDef):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Call) and isinstance(node.func, (ast.Name, ast.Attribute)):
                    # a bare call (parse(...), validate_device(...)) or a model's own (X.model_validate(...));
                    # JigStatus.parse(line) reads a protocol reply, not a config
                    name = node.func.id if isinstance(node.func, ast.Name) else node.func.attr
                    if isinstance(node.func, ast.Attribute) and name != "model_validate":
                        continue
                    if name in names and (f.name, fn.name) not in allowed:
                        found.append(f"{f.name}:{node.lineno} {fn.name}: {name}()")
    assert not found, found
    assert len(files) > 20  # the scan reaches the parts


def test_config_docs_read_as_yaml_not_python_reprs() -> None:
    """docs/config.md's types and defaults in the reader's notation: no pydantic or typing reprs
    (``FieldInfo(``, ``Annotated[``, ``Optional[``, ``<class``), None written as YAML's null, and
    I2C addresses in hex as data sheets give them (MMA8451: 0x1d with SA0 high, 0x1c low; 24Cxx
    EEPROMs 0x50..0x57; TCA9548A 0x70..0x77)."""
    text = (REPO / "docs" / "config.md").read_text()
    for repr_text in ("FieldInfo(", "Annotated[", "Optional[", "Union[", "Literal[", "<class", "NoneType", "Strict("):
        assert repr_text not in text, repr_text
    rows = {}
    for title, table in re.findall(r"\n## `([^`]+)`\n(.*?)(?=\n## |\Z)", text, flags=re.S):
        for row in re.findall(r"^\| `(\w+)` \| (.+?) \| (.+?) \| (.+?) \|", table, flags=re.M):
            rows[(title, row[0])] = row[1:]
    assert rows[("device (driver: mma8451)", "address")] == ("int", "`0x1d`", "0x00 to 0x7f")
    assert rows[("device.eeprom (driver: mma8451)", "address")] == ("int", "`0x50`", "0x50 to 0x57")
    assert rows[("device.mux (driver: mma8451)", "address")] == ("int", "`0x70`", "0x70 to 0x77")
    assert rows[("device (driver: mma8451)", "range_g")][0] == "2 / 4 / 8"
    assert rows[("device (driver: simulated)", "seated_deg")][0] == "list of 3 float \\| null"


def test_station_config_copies_no_schema_field(tmp_path: Path) -> None:
    """Issue 52: StationConfig holds the validated schema and derives every value from it (read-only), so
    a section replaced through with_sections carries its derived values along and a cross-key rule is
    checked again; nothing can be assigned beside the schema."""
    import dataclasses

    from accelcal_station.config.schema import CaptureSection, NvmSection, PlanSection
    from accelcal_station.errors import ConfigError
    from accelcal_station.station.settings import StationConfig

    cfg = StationConfig.load(default_config_path())
    assert set(cfg.__dataclass_fields__) == {"schema", "text", "path", "store_override", "workdir"}
    assert (cfg.design, cfg.model, cfg.nvm_write) == (cfg.schema.plan.design, str(cfg.schema.plan.model),
                                                      (cfg.schema.nvm or NvmSection()).write)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.model = "6"  # type: ignore[misc]
    six = cfg.with_sections(plan=PlanSection(design="an4399-6", model=6),
                            capture=CaptureSection(min_samples=77), nvm=NvmSection(write=False, offset_trim=True))
    assert (six.design, six.model, six.capture.min_samples, six.nvm_write, six.offset_trim) == \
        ("an4399-6", "6", 77, False, True)
    assert (cfg.model, cfg.capture.min_samples) != ("6", 77)  # the original is untouched
    with pytest.raises(ConfigError, match="nvm.offset_trim: the 15-parameter model"):
        six.with_sections(plan=PlanSection(model=15))
    with pytest.raises(ConfigError, match="capture.k_leave must be >= capture.k_enter"):
        cfg.with_sections(capture=CaptureSection(k_enter=5.0, k_leave=4.0))
    # --store is the one value the command line adds; a relative store.path is taken from the folder of the load
    assert StationConfig.load(default_config_path(), store_override=tmp_path / "x.sqlite").store_file == \
        tmp_path / "x.sqlite"
