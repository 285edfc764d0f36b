"""The shared YAML reader: model, config and catalogue files are read with bounded work; refusals name the place."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest
import yaml

from compd.errors import ConfigFileError, InputFileError, ModelFileError
from compd.files.modelfile import load_model, parse_model
from compd.files.yamlplace import (
    MAX_YAML_BYTES,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
    NodeTree,
    parse_yaml,
    where,
)
from compd.service.config.loading import load_config

from .test_modelfile import VALID


def refused(text: str) -> str:
    with pytest.raises(ModelFileError) as info:
        parse_model(text, "m.yaml")
    return str(info.value)


def test_a_duplicate_key_is_an_error_naming_both_lines() -> None:
    """A key given twice in one mapping is refused, naming its line and the first one, not silently overwritten."""
    text = VALID.replace("sample_time_s: 1.0\n", "sample_time_s: 1.0\nname: again\n")
    message = refused(text)
    assert message.startswith("m.yaml: line 4: duplicate key 'name' (first on line 2)")
    assert "duplicate key 'a'" in refused("schema: compd.model/1\nx: {a: 1, a: 2}\n")


def test_a_duplicate_key_in_a_config_is_an_error(tmp_path: Path) -> None:
    """The config loader shares the reader: a repeated key is a ConfigFileError naming the file."""
    path = tmp_path / "compd.yaml"
    path.write_text("schema: compd.config/1\nperiod_s: 1\nperiod_s: 2\n")
    with pytest.raises(ConfigFileError, match=r"compd.yaml: line 3: duplicate key 'period_s'"):
        load_config(path)


def test_aliases_that_would_expand_beyond_the_limit_are_refused_before_expanding() -> None:
    """A small file whose aliases nest into 10^6 values (an alias bomb, as in provenance lists) is refused on its line.

    (The issue's bomb was 10^8 values; 10^6 shows the same and stays within
    a test machine's memory where the reader has no limit.)
    """
    lines = ["schema: compd.model/1", "x0: &a0 [" + ", ".join(["1.0"] * 10) + "]"]
    for level in range(1, 6):
        lines.append(f"x{level}: &a{level} [" + ", ".join([f"*a{level - 1}"] * 10) + "]")
    text = "\n".join(lines) + "\n"
    assert len(text) < 2_000
    message = refused(text)
    assert f"holds more than {MAX_YAML_NODES} values (aliases expanded)" in message
    assert message.startswith("m.yaml: line 6:")


def test_a_few_aliases_are_still_fine() -> None:
    """Aliases within the limit load as before (the same value where the alias stands)."""
    data, _ = parse_yaml("a: &x [1, 2]\nb: *x\nc: {<<: {p: 1}, q: 2}\n", "f.yaml", InputFileError)
    assert data == {"a": [1, 2], "b": [1, 2], "c": {"p": 1, "q": 2}}


def test_deep_nesting_is_refused_not_a_recursion_error() -> None:
    """100,000 nested flow lists are a clear error naming the nesting limit, not a RecursionError."""
    message = refused("schema: compd.model/1\nx: " + "[" * 100_000 + "]" * 100_000 + "\n")
    assert f"nested deeper than {MAX_YAML_DEPTH} levels" in message


def test_a_file_over_the_size_limit_is_refused(tmp_path: Path) -> None:
    """A model file larger than the limit is refused by size, before it is parsed."""
    path = tmp_path / "big.yaml"
    path.write_text(VALID + "#" * MAX_YAML_BYTES)
    with pytest.raises(ModelFileError, match=f"larger than {MAX_YAML_BYTES} bytes"):
        load_model(path)


def test_a_long_value_is_cut_in_the_message() -> None:
    """A value of hundreds of kilobytes is shown cut to a few dozen characters, never echoed whole."""
    huge = "x" * 500_000
    message = refused(VALID.replace("sample_time_s: 1.0", f"sample_time_s: {huge}"))
    assert "sample_time_s" in message and len(message) < 500


def test_a_fifo_or_a_device_is_refused_without_blocking(tmp_path: Path) -> None:
    """A FIFO or /dev/zero given as a model file is 'not a regular file' at once (no hang, no MemoryError)."""
    fifo = tmp_path / "model.fifo"
    os.mkfifo(fifo)
    messages: list[str] = []

    def read_both() -> None:
        for path in (fifo, Path("/dev/zero")):
            try:
                load_model(path)
            except ModelFileError as exc:
                messages.append(str(exc))

    reader = threading.Thread(target=read_both, daemon=True)
    reader.start()
    reader.join(timeout=20)  # only a give-up bound: the reads return at once or never
    assert not reader.is_alive(), "reading a FIFO blocked"
    assert messages == [
        f"{path}: not a regular file. Give the path of a YAML file" for path in (fifo, "/dev/zero")
    ]


def test_an_integer_of_5000_digits_is_refused_naming_its_place() -> None:
    """An integer longer than Python converts (4,300 digits) is a ModelFileError on its line, not a ValueError."""
    message = refused(
        VALID.replace("den: [0.002098, 2.379, 1.0]", f"den: [0.002098, {'7' * 5000}]")
    )
    assert message.startswith("m.yaml: line 18 (outputs.disp_z_um.submodels[0].tf.den[1]): ")
    assert "an integer of 5000 digits (at most 4300)" in message and len(message) < 500


def test_a_date_that_is_no_date_in_a_config_is_a_config_error(tmp_path: Path) -> None:
    """A scalar YAML types as a date but no calendar holds (2024-13-45) is refused naming file and place."""
    path = tmp_path / "compd.yaml"
    path.write_text("schema: compd.config/1\nperiod_s: 1\nmachine_id: 2024-13-45\n")
    with pytest.raises(ConfigFileError, match=r"compd.yaml: line 3 \(machine_id\): '2024-13-45'"):
        load_config(path)


#: Documents the event-built path takes as they are, and ones it hands to the composer.
AS_COMPOSED = {
    "empty": "",
    "a scalar": "3",
    "types": "a: yes\nb: 0x1f\nc: 1_000\nd: .inf\ne: ~\nf: 2024-01-02T03:04:05Z\ng: '1'\nh: !!str 12\n",
    "keys": "~: 1\n1: a\n2.5: b\n",
    "nested": "a:\n  - {b: [1, 2, {c: d}]}\n  - - x\n    - y\n",
    "anchors": "a: &x [1, 2]\nb: *x\n",
    "a merge key": "base: &b {x: 1}\nc:\n  <<: *b\n  y: 2\n",
    "tags": "s: !!set {a, b}\nb: !!binary aGVsbG8=\no: !!omap [a: 1]\n",
}


@pytest.mark.parametrize("text", AS_COMPOSED.values(), ids=AS_COMPOSED.keys())
def test_a_document_built_from_events_is_the_one_composing_builds(text: str) -> None:
    """The document loaded without a node tree is, value for value, what PyYAML's safe loader builds."""
    data, _ = parse_yaml(text, "x.yaml", InputFileError)
    assert repr(data) == repr(yaml.load(text, Loader=yaml.CSafeLoader))


def test_every_bundled_file_loads_as_composing_loads_it() -> None:
    """Each YAML file in config/ (models with a 60 x 60 covariance, configs) loads as PyYAML loads it."""
    files = sorted(Path(__file__).parents[1].joinpath("config").glob("*.yaml"))
    assert len(files) >= 8
    for path in files:
        text = path.read_text()
        data, tree = parse_yaml(text, path, InputFileError)
        assert repr(data) == repr(yaml.load(text, Loader=yaml.CSafeLoader)), path
        assert built_from_events(tree), f"{path.name}: loaded without composing its nodes"


def built_from_events(tree: NodeTree) -> bool:
    return not tree._composed  # what these tests check: no node composed yet


def test_only_an_error_composes_the_node_tree_for_its_line() -> None:
    """A valid model file keeps no nodes; the first error needing a line composes them, once."""
    data, tree = parse_yaml(VALID, "m.yaml", ModelFileError)
    assert isinstance(data, dict) and built_from_events(tree)
    assert where(tree, ("outputs",)).startswith("line ")
    assert not built_from_events(tree)
    with pytest.raises(ModelFileError, match=r"line \d+ \(outputs"):
        parse_model(VALID.replace("outputs:", "outputs:\n  bogus_key_here: 1\n  _x:", 1))


@pytest.mark.parametrize("machine_id", ["mill-1\n", "mill 1", "mühle"])
def test_a_pattern_holds_to_the_end_of_the_value(machine_id: str) -> None:
    """Patterns are matched by Python's re (no Rust regex engine in the daemon): a trailing newline is refused too."""
    from compd.service.config.docs import ConfigDoc

    with pytest.raises(ValueError, match="should match pattern"):
        ConfigDoc.model_validate({"machine_id": machine_id})
