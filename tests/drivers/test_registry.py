"""A third-party driver plugs in through the ``compd.drivers`` entry-point group, untouched compd."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
import yaml

from compd.drivers.registry import BUILTIN, driver_names, load_driver_type
from compd.errors import ConfigFileError
from compd.service.config.loading import load_config
from tests.acceptance.conftest import machine_doc

BUNDLED_MODEL = Path(__file__).parents[2] / "config" / "simulated_model.yaml"


@pytest.fixture
def installed_plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A package ``mybus`` installed beside compd: a module and its dist-info with the entry point."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "mybus.py").write_text(
        textwrap.dedent(
            """
            from pydantic import BaseModel

            class MyBusSettings(BaseModel):
                station: int

            class MyBusDriver:
                settings_model = MyBusSettings
                address_syntax = "as REGISTER, a whole number"

                def __init__(self, settings, *, now, base_dir):
                    self.settings = settings

                @staticmethod
                def validate_address(address, *, writable, settings=None):
                    if address == "15":
                        raise TypeError("bad table")
                    if not address.isdigit():
                        raise ValueError("not a register number")

                @staticmethod
                def footprint(address, settings):
                    if address == "13":  # defects of this plugin, on purpose
                        raise KeyError(address)
                    return frozenset({(("mybus", settings.station), int(address))})

                @staticmethod
                def raw_range(address, settings):
                    if address == "14":
                        raise IndexError("range table")
                    return None

                @staticmethod
                def check_host(settings, *, base_dir, written):
                    if settings.station == 99:
                        raise RuntimeError("no station 99")
                    return None

                async def open(self): ...
                async def read(self, points): return {}
                async def write(self, values): ...
                async def close(self): ...
            """
        )
    )
    info = site / "mybus-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mybus\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[compd.drivers]\nmybus = mybus:MyBusDriver\n")
    monkeypatch.syspath_prepend(str(site))
    load_driver_type.cache_clear()
    yield site
    load_driver_type.cache_clear()


def test_an_installed_driver_is_named_loaded_and_checked(installed_plugin: Path, tmp_path: Path):
    assert "mybus" in driver_names() and "modbus" in driver_names()
    kind = load_driver_type("mybus")
    assert kind.__name__ == "MyBusDriver"

    doc = machine_doc(tmp_path, BUNDLED_MODEL, simulation={"scenario": "production"})
    del doc["simulation"]
    doc["drivers"]["plc"] = {"type": "mybus", "settings": {"station": 3}}
    for signal in doc["signals"].values():
        signal["address"] = "7"
    for output in doc["outputs"].values():
        output["address"] = "100"
    doc["status"]["status_address"], doc["status"]["heartbeat_address"] = "101", "102"
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc))
    config = load_config(path)
    assert config.build_drivers(now=lambda: 0.0)["plc"].settings.station == 3

    doc["signals"][next(iter(doc["signals"]))]["address"] = "T1"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(
        ConfigFileError, match=r"not a register number.*as REGISTER, a whole number"
    ):
        load_config(path)


@pytest.mark.parametrize(
    ("station", "offset_address", "said"),
    [
        (3, "13", "could not tell the cells of '13': KeyError: '13'"),
        (3, "14", "could not tell the whole numbers '14' holds: IndexError: range table"),
        (
            99,
            "100",
            "could not tell whether its settings work on this host: RuntimeError: no station 99",
        ),
        (3, "15", "could not tell whether '15' is an address: TypeError: bad table"),
    ],
)
def test_a_driver_hook_that_raises_is_named_not_a_traceback(
    installed_plugin: Path, tmp_path: Path, station: int, offset_address: str, said: str
):
    """A plugin's config-time hook raising: check-config names the entry, its type, what it raised."""
    doc = machine_doc(tmp_path, BUNDLED_MODEL, simulation={"scenario": "production"})
    del doc["simulation"]
    doc["drivers"]["plc"] = {"type": "mybus", "settings": {"station": station}}
    for signal in doc["signals"].values():
        signal["address"] = "7"
    for output in doc["outputs"].values():
        output["address"] = offset_address
    doc["status"]["status_address"], doc["status"]["heartbeat_address"] = "101", "102"
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigFileError) as caught:
        load_config(path)
    message = " ".join(str(caught.value).split())
    assert f"driver 'plc' (type 'mybus') {said}" in message
    assert "report it to its maintainer" in message


@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_each_builtin_name_is_its_class_in_the_module_it_names(name: str):
    """A built-in type loads from the module ``BUILTIN`` names (a protocol's sub-package: its ``driver``)."""
    module, _, attribute = BUILTIN[name].partition(":")
    kind = load_driver_type(name)
    assert (kind.__module__, kind.__name__) == (module, attribute)
    assert module.startswith("compd.drivers.")
