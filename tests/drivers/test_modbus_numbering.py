"""Modbus addresses as users write them: Modicon references (40101, 30001) and numbers counted from 1.

Manuals and HMIs number registers from 1 with the table in front
(``40101`` is holding register 101, address 100 on the wire); compd reads
them so, says how, and misspelt setting keys name the key meant.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from compd.drivers.modbus.addresses import parse_address, translation_note
from tests.clirun import compd_result as compd

from ..service.daemon_setup import merge, simulated_doc
from .modbus_server import running_tcp_server


@pytest.fixture(scope="module")
def plc() -> Iterator[int]:
    """A pymodbus server on 127.0.0.1 (modbus_server.py); yields its port."""
    with running_tcp_server() as port:
        yield port


@pytest.mark.parametrize(
    ("written", "wire"),
    [
        ("40101", "holding:100"),
        ("30001:int16", "input:0:int16"),
        ("400101:int32", "holding:100:int32"),
        ("365536", "input:65535"),
        ("00001", "coil:0"),
        ("10016", "discrete:15"),
        ("holding:101:base=1", "holding:100"),
        ("input:3:float32:base=1:word=little", "input:2:float32:word=little"),
    ],
)
def test_modicon_and_one_based_addresses_are_the_wire_address_minus_one(written, wire):
    """A Modicon reference or a base=1 address is the 0-based address one lower, and a note says so."""
    assert parse_address(written) == parse_address(wire)
    note = translation_note(written)
    assert note is not None and wire.split(":")[0] in note and "on the wire" in note


def test_plain_addresses_are_unchanged_and_get_no_note():
    """TABLE:ADDRESS stays 0-based as on the wire; 0 with base=1 and a 5-digit 2xxxx are refused."""
    assert parse_address("holding:40101").address == 40101
    assert translation_note("holding:100:int32") is None
    for bad, match in (("holding:0:base=1", "count from 1"), ("20001", "Modicon")):
        with pytest.raises(ValueError, match=match):
            parse_address(bad)


def test_probe_reads_a_modicon_reference_from_a_real_server(plc):
    """compd probe 30001:int16 reads input register 0 of a pymodbus server (-1234)."""
    code, out, err = compd(
        "probe", "modbus", "--set", "host=127.0.0.1", "--set", f"port={plc}", "30001:int16"
    )
    assert code == 0, err
    assert "-1234" in out


def check_config(tmp_path: Path, address: str) -> tuple[int, str, str]:
    """compd check-config on the simulated config with T_spindle_degC on a Modbus PLC at ``address``."""
    doc = merge(
        simulated_doc(),
        {
            "state": {"directory": str(tmp_path / "state")},
            "drivers": {"plc": {"type": "modbus", "settings": {"host": "127.0.0.1"}}},
            "signals": {"T_spindle_degC": {"driver": "plc", "address": address}},
        },
    )
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc))
    return compd("check-config", path)


def test_check_config_notes_the_translation(tmp_path):
    """check-config accepts a signal at 30011:int16 and prints how it read it: input:10 on the wire."""
    code, out, err = check_config(tmp_path, "30011:int16")
    assert code == 0, err
    assert "note: signals.T_spindle_degC.address: 30011 is Modicon numbering" in out
    assert "input:10 on the wire" in out


def test_an_unknown_set_key_lists_the_valid_ones():
    """--set hots=... names 'host' as the key meant and lists the keys the driver takes."""
    code, _, err = compd("probe", "modbus", "--set", "hots=10.0.0.1", "holding:1")
    assert code == 2
    assert "did you mean 'host'?" in err and "port, serial_port" in err


def test_a_misspelt_config_key_names_the_key_meant(tmp_path):
    """A config with max_rate_um_per_sec, or a driver setting 'hots', is refused naming the key meant."""
    for changes, meant in (
        ({"outputs": {"Y": {"max_rate_um_per_sec": 1.0}}}, "did you mean 'max_rate_um_per_s'?"),
        ({"drivers": {"machine": {"settings": {"lop": True}}}}, "did you mean 'loop'?"),
    ):
        doc = merge(simulated_doc(), {"state": {"directory": str(tmp_path / "state")}, **changes})
        path = Path(tmp_path / "compd.yaml")
        path.write_text(yaml.safe_dump(doc))
        code, _, err = compd("check-config", path)
        assert code == 2 and meant in err, err


def test_a_table_address_that_looks_like_modicon_gets_the_hint(tmp_path):
    """input:30001 (or a 4xxxx in the input table) is read as written, and check-config says what Modicon would mean."""
    assert parse_address("input:30001:int16").address == 30001
    note = translation_note("input:40011:int16")
    assert note is not None and "holding register 11, not input register 40011" in note
    assert "write 40011:int16 or holding:10:int16" in note
    code, out, err = check_config(tmp_path, "input:30011:int16")
    assert code == 0, err
    words = " ".join(out.split())
    assert "input:30011 is read as input address 30011 on the wire" in words
    assert "input register 11 counted from 1" in words and "input:10:int16" in words
