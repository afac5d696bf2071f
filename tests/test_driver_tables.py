"""Driver tables ([arm], [turntable], [spectrometer], [light]) are validated through the drivers'
declared settings before anything starts: every key with a wrong type is one line naming the
file, the table, the key and the value, and the CLI exits 2."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

from bench.builders.emulated import emulated_arm_config
from bench.builders.light import LightTable
from bench.builders.tables import validate_driver_tables
from bench.core.errors import ConfigError
from bench.core.parsing import read_toml
from drivers.dynamixel.config import ArmConfig, AxisConfig as ServoAxisConfig
from drivers.modbus.config import AxisConfig as StageAxisConfig
from drivers.ocean.config import OceanConfig
from tests.helpers.cli import run_main

ROOT = Path(__file__).resolve().parents[1]
EMULATED = ROOT / "fixtures" / "benches" / "emulated.toml"
REAL = ROOT / "fixtures" / "benches" / "real-template.toml"

#: a value of the wrong type for every scalar or list setting (a table), and for a table (a string)
WRONG_FOR_VALUE = {"wrong": "type"}
WRONG_FOR_TABLE = "x"


def _cases() -> list[tuple[str, str, tuple[str, ...]]]:
    """(kind, table, key path) for every declared key of every driver table."""
    cases = []
    for kind in ("emulated", "real"):
        for key in ArmConfig.model_fields:
            if key != "port" or kind == "real":  # the emulated body owns the arm's port
                cases.append((kind, "arm", (key,)))
        for key in ServoAxisConfig.model_fields:
            if key != "joint":  # the joint is the table's name, not a key
                cases.append((kind, "arm", ("axes", "source", key)))
        cases += [(kind, "turntable", (key,)) for key in StageAxisConfig.model_fields]
        cases += [(kind, "spectrometer", (key,)) for key in OceanConfig.model_fields]
        cases += [(kind, "light", (key,)) for key in LightTable.model_fields]
    return cases


def _description(kind: str) -> dict:
    d = read_toml(REAL if kind == "real" else EMULATED, "bench config")
    d.setdefault("turntable", {"port": "tcp://127.0.0.1:1"} if kind == "real" else {})
    d.setdefault("light", {})
    if kind == "emulated":  # an [arm.axes] table replaces the emulated arm's axes: start from them
        d["arm"] = {"axes": emulated_arm_config(d, "")["axes"]}
    return d


@pytest.mark.parametrize("kind,table,path", _cases(), ids=lambda c: ".".join(c) if isinstance(c, tuple) else c)
def test_every_driver_key_with_a_wrong_type_is_one_line(kind, table, path):
    d = copy.deepcopy(_description(kind))
    node = d.setdefault(table, {})
    for part in path[:-1]:
        node = node.setdefault(part, {})
    wrong = WRONG_FOR_TABLE if path[-1] in ("axes", "kinematics") else WRONG_FOR_VALUE
    node[path[-1]] = wrong
    with pytest.raises(ConfigError) as err:
        validate_driver_tables(d, "bench config B.toml")
    msg = str(err.value)
    assert "\n" not in msg and len(msg) < 300, msg
    assert msg.startswith(f"bench config B.toml [{table}]"), msg
    assert path[-1] in msg, msg


def test_the_fixtures_pass():
    for path in (EMULATED, REAL):
        validate_driver_tables(read_toml(path, "bench config"), str(path))


@pytest.mark.parametrize("table,key,value", [("turntable", "gear_ratio", "x"), ("spectrometer", "checksum", "x")])
def test_cli_refuses_before_any_emulator_starts(tmp_path, capsys, table, key, value):
    bench = tmp_path / "b.toml"
    text = EMULATED.read_text()
    line = f'{key} = "{value}"\n'
    # into the fixture's table when it has one (emulated.toml declares [spectrometer]), else a new table
    text = (text.replace(f"\n[{table}]", f"\n[{table}]\n{line}", 1) if f"\n[{table}]" in text
            else text + f"\n[{table}]\n{line}")
    bench.write_text(text)
    code, out, err = run_main(capsys, "plan", ROOT / "fixtures" / "plans" / "cie-spectral.toml", "--bench", bench)
    assert code == 2, err
    line = err.strip()
    assert "\n" not in line and f"[{table}]" in line and key in line and repr(value) in line, line
    assert str(bench) in line
