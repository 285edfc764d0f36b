"""The effect catalogue: glob patterns to physical effects, user entries first, errors that name file, line and fix."""

from pathlib import Path

import pytest

from compd.errors import InputFileError
from compd.files.effects import UNKNOWN_EFFECT, load_catalogue, parse_catalogue

USER = """\
schema: compd.effects/1
effects:
  - match: spindle_power_kw
    effect: our milling head's process heat
  - match: ["T_oil_*", "hydraulic_*"]
    effect: hydraulic power pack
"""


@pytest.fixture(scope="module")
def bundled():
    return load_catalogue()


@pytest.mark.parametrize(
    ("signal", "words"),
    [
        ("spindle_power_kw", "cutting process"),
        ("feed_x_mm_per_min", "ball screw"),
        ("feed_z_mm_per_min", "feed drive"),
        ("door_open", "door opening"),
        ("T_coolant_degC", "coolant"),
        ("T_ambient_degC", "ambient"),
        ("T_shopfloor_degC", "ambient"),
        ("T_column_back_degC", "column"),
        ("t_spindle_degc", "spindle bearing"),
    ],
)
def test_bundled_catalogue_names_the_effects_of_the_usual_signals(
    bundled, signal: str, words: str
) -> None:
    """The bundled catalogue maps the usual machine signals (any letter case) to their physical effect."""
    assert words in bundled.effect_for(signal)


def test_a_signal_nothing_matches_has_an_unknown_effect(bundled) -> None:
    """A column no pattern matches is an 'unknown effect', never a guess."""
    assert bundled.effect_for("vibration_rms_g") == UNKNOWN_EFFECT


def test_first_match_wins(bundled) -> None:
    """T_coolant_degC matches both the coolant entry and the generic T_* entry; the earlier (coolant) wins."""
    generic = next(e for e in bundled.entries if "T_*" in e.patterns)
    assert generic.matches("T_coolant_degC")  # it would match, but comes later
    assert "coolant" in bundled.effect_for("T_coolant_degC")
    assert "local structural heat" in bundled.effect_for("T_unnamed_sensor_degC")


def test_user_entries_take_precedence_and_extend(tmp_path: Path) -> None:
    """A --catalogue file's entries are tried first: they override bundled ones and add new signals."""
    path = tmp_path / "mine.yaml"
    path.write_text(USER)
    catalogue = load_catalogue(path)
    assert catalogue.effect_for("spindle_power_kw") == "our milling head's process heat"
    assert catalogue.effect_for("T_oil_tank_degC") == "hydraulic power pack"
    assert "ball screw" in catalogue.effect_for("feed_x_mm_per_min")  # bundled still there
    assert catalogue.entry_for("spindle_power_kw").source == str(path)


HEAD = "schema: compd.effects/1\neffects:\n"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            HEAD + "  - match: a*\n    efect: x\n",
            "line 4 (effects[0].efect): unknown key 'efect'",
        ),
        (
            HEAD + "  - match: a*\n",
            "line 3 (effects[0].effect): required key 'effect' is missing",
        ),
        (
            HEAD + "  - match: ['']\n    effect: x\n",
            "line 3 (effects[0].match): a pattern is empty",
        ),
        ("schema: compd.effects/1\neffects: []\n", "line 2 (effects)"),
        ("effects:\n  - match: a*\n    effect: x\n", "not an effect catalogue"),
        ("schema: compd.effects/1\neffects: [\n", "not valid YAML"),
    ],
)
def test_a_malformed_catalogue_is_refused_naming_file_place_and_fix(
    text: str, message: str
) -> None:
    """Unknown or missing keys, empty patterns, no entries, no schema and bad YAML are errors with a place."""
    with pytest.raises(InputFileError) as caught:
        parse_catalogue(text, "mine.yaml")
    assert str(caught.value).startswith("mine.yaml: ")
    assert message in str(caught.value)


def test_an_unreadable_catalogue_is_an_input_error(tmp_path: Path) -> None:
    """A --catalogue path that cannot be read is reported as such, not as a crash."""
    with pytest.raises(InputFileError, match="cannot read the effect catalogue"):
        load_catalogue(tmp_path / "missing.yaml")
