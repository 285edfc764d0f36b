"""compd diagnose: which effect the model misses, end to end on a record with a known missing effect."""

import json
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from tests.residue_case import POWER_GAIN_UM_PER_KW, POWER_TAU_S, signals, write_case, zoh_lag


@pytest.fixture(scope="module")
def case(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return write_case(tmp_path_factory.mktemp("residue_case"))


def run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def diagnose_json(capsys: pytest.CaptureFixture[str], *argv: object) -> dict:
    code, out, err = run(capsys, "diagnose", *argv, "--json")
    assert code == 0, err
    return json.loads(out)


def test_json_ranks_spindle_power_first_as_cutting_process_heat(case, capsys) -> None:
    """The missing cutting-process effect is found: spindle power first, its effect, gain and time constant."""
    report = diagnose_json(capsys, *case)
    best = report["candidates"][0]
    assert best["signal"] == "spindle_power_kw"
    assert "cutting process heat" in best["effect"]
    assert best["explained_percent"] > 80.0
    assert best["sign"] == 1 and best["significant"] is True
    assert best["gain_um_per_unit"] == pytest.approx(POWER_GAIN_UM_PER_KW, rel=0.1)
    assert best["time_constant_s"] == pytest.approx(POWER_TAU_S, rel=0.15)
    assert report["missing_effect"] == "spindle_power_kw" and report["residue_white"] is False
    assert report["verdict"].startswith("most likely missing effect: cutting process heat")


def test_json_candidates_have_the_contract_keys_and_default_set(case, capsys) -> None:
    """Each candidate has signal, effect, explained_percent; defaults exclude outputs, *_um columns and model inputs."""
    report = diagnose_json(capsys, *case)
    signals_ = [c["signal"] for c in report["candidates"]]
    assert set(signals_) == {
        "spindle_speed_rpm",
        "spindle_power_kw",
        "feed_x_mm_per_min",
        "door_open",
        "T_coolant_degC",
        "T_ambient_degC",
    }
    shares = [c["explained_percent"] for c in report["candidates"]]
    assert shares == sorted(shares, reverse=True)
    for c in report["candidates"]:
        assert {
            "signal",
            "effect",
            "explained_percent",
            "time_constant_s",
            "lag_s",
            "xcorr_bound",
        } <= set(c)


def test_without_the_causing_signal_no_effect_is_invented(case, capsys) -> None:
    """--candidates without spindle power (or its coolant echo): the verdict says the effect is not among them."""
    report = diagnose_json(
        capsys, *case, "--candidates", "door_open,T_ambient_degC,feed_x_mm_per_min"
    )
    assert [c["signal"] for c in report["candidates"]].count("spindle_power_kw") == 0
    assert report["missing_effect"] is None
    assert "not among the candidates" in report["verdict"]


def test_white_residue_says_so(tmp_path: Path, capsys) -> None:
    """A record the model explains up to white noise: the verdict says the residue is white."""
    model, _ = write_case(tmp_path)
    frame = signals()
    exact = 4.0 * zoh_lag(frame["T_spindle_degC"].to_numpy(), 600.0)  # the model, exactly
    frame["disp_z_um"] = exact + np.random.default_rng(1).normal(0.0, 0.1, len(frame))
    frame.to_csv(tmp_path / "white.csv", index=False, float_format="%.6f")
    report = diagnose_json(capsys, model, tmp_path / "white.csv")
    assert report["residue_white"] is True and report["missing_effect"] is None
    assert report["verdict"] == "residue is white: no missing effect stands out"


def test_table_shows_rank_effect_and_verdict(case, capsys) -> None:
    """The human output is a table of the top N candidates with their effects, then a one-line verdict."""
    code, out, err = run(capsys, "diagnose", *case, "--top", "3")
    assert code == 0, err
    assert "explained" in out and "cutting process heat" in out  # (headers wrap between words)
    ranks = [line.split("│")[1].strip() for line in out.splitlines() if line.startswith("│")]
    assert [r for r in ranks if r] == ["1", "2", "3"]  # (a long cell may wrap onto a second line)
    verdict = out[out.index("most likely missing effect") :]
    assert " ".join(verdict.split()).startswith("most likely missing effect: cutting process heat")


@pytest.mark.parametrize("columns", [100, 60])
def test_every_line_fits_the_terminal_and_no_word_is_cut(
    case, capsys, monkeypatch, columns
) -> None:
    """At COLUMNS=N the tables and the verdict fit N columns, wrapped between words, nothing cut (…)."""
    monkeypatch.setenv("COLUMNS", str(columns))
    code, out, err = run(capsys, "diagnose", *case)
    assert code == 0, err
    assert "…" not in out
    assert max(len(line) for line in out.splitlines()) <= columns
    verdict = " ".join(out[out.index("most likely missing effect") :].split())
    assert "cutting process heat" in verdict and "explains" in verdict


def test_user_catalogue_renames_the_effect(case, tmp_path: Path, capsys) -> None:
    """--catalogue entries take precedence over the bundled ones in the report."""
    catalogue = tmp_path / "mine.yaml"
    catalogue.write_text(
        "schema: compd.effects/1\neffects:\n  - match: spindle_power*\n    effect: roughing heat of head 2\n"
    )
    report = diagnose_json(capsys, *case, "--catalogue", catalogue)
    assert report["candidates"][0]["effect"] == "roughing heat of head 2"


def test_bad_catalogue_or_unknown_candidate_exits_2(case, tmp_path: Path, capsys) -> None:
    """A malformed catalogue or a candidate the file lacks ends with exit status 2 and a message naming it."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("schema: compd.effects/1\neffects:\n  - match: x\n")
    code, _, err = run(capsys, "diagnose", *case, "--catalogue", bad)
    assert code == 2 and "bad.yaml: line 3" in err
    code, _, err = run(capsys, "diagnose", *case, "--candidates", "no_such_column")
    assert code == 2 and "no_such_column" in err


def test_a_found_effect_the_rule_refuses_is_said_not_to_survive() -> None:
    """A named signal whose extension removes < 10 % of the held-out error (or helps few folds) would not survive."""
    from types import MappingProxyType

    import numpy as np
    import scipy.signal

    from compd.model.diagnose import diagnose_residue
    from compd.toolkit.analysis import DiagnosisResult
    from compd.toolkit.extendjudge import RULE, HeldOut

    rng = np.random.default_rng(0)
    n = 6 * 3600 // 10
    door = (rng.random(n) < 0.02).astype(float)
    effect = scipy.signal.lfilter([0.05], [1, -0.95], door)
    residue = 0.05 * effect + rng.normal(0, 0.001, n)
    diagnosis = diagnose_residue(residue, {"door_open": door}, 10.0)
    assert diagnosis.missing_effect is not None
    effects = MappingProxyType({"door_open": "door openings"})

    def judged(rms_after_um: tuple[float, ...]) -> DiagnosisResult:
        held = HeldOut("leave one of 3 blocks out", 90.0, 90.5, 1.0, float(np.mean(rms_after_um)),
                       (1.0, 1.0, 1.0), rms_after_um)  # fmt: skip
        return DiagnosisResult("z", "z", diagnosis, effects, extended={"door_open": held})

    small = judged((0.95, 0.95, 0.95)).verdict  # 5 % of the error, on every fold
    assert "would not survive" in small and RULE in small and "removes 5 %" in small
    few_folds = judged((0.5, 1.05, 1.05)).verdict  # 13 % of the error, on one fold of three
    assert "would not survive" in few_folds and "lowers it on 1 of 3 folds" in few_folds
    assert "would not survive" not in judged((0.8, 0.8, 0.8)).verdict


def test_a_coarsely_logged_record_is_diagnosed_on_fewer_blocks(tmp_path: Path, capsys) -> None:
    """72 samples of 10 min (12 h logged as coarsely as issue 20's record C) are diagnosed, not refused.

    A record of 60-99 samples is cut into 3 or 4 blocks of at least 20 instead
    of the default 5; the missing power effect is still found.
    """
    model, _ = write_case(tmp_path)
    # A logger's 10-min means: 72 samples, the rough cut among them.
    frame = signals().groupby(np.arange(4320) // 60).mean()
    frame["time_s"] = np.arange(len(frame)) * 600.0
    frame.to_csv(tmp_path / "coarse.csv", index=False, float_format="%.6f")
    report = diagnose_json(capsys, model, tmp_path / "coarse.csv")
    assert report["candidates"], report
    assert report["candidates"][0]["signal"] == "spindle_power_kw"


def test_too_short_a_record_says_how_many_samples_and_hours_it_needs(
    tmp_path: Path, capsys
) -> None:
    """Fewer than 64 samples: exit 2 naming the file, the 64 samples needed and what that is in hours."""
    model, _ = write_case(tmp_path)
    signals().iloc[::30].iloc[:50].to_csv(tmp_path / "short.csv", index=False)
    code, _, err = run(capsys, "diagnose", model, tmp_path / "short.csv")
    assert code == 2
    assert "short.csv" in err and "50 samples" in err and "64" in err
    assert "5.33 h at 300 s" in err


def test_the_last_hour_of_a_long_record_is_judged_on_folds_of_that_hour(case, capsys) -> None:
    """``--from`` inside the record's last fold: the extension is judged on blocks of the scored part.

    The whole record's four blocks would leave the last hour in one of them,
    with nothing to hold out against (it used to end in "no fold has both
    held-out and fitted samples").
    """
    report = diagnose_json(capsys, *case, "--from", "11:00")
    judged = [c["extended"] for c in report["candidates"] if c.get("extended")]
    assert judged, report["candidates"][0]
    assert all("of the scored part" in j["folds"] for j in judged)


@pytest.fixture
def terminal_100(monkeypatch: pytest.MonkeyPatch) -> None:
    """diagnose prints to a 100-column terminal (rich's console at width 100)."""
    from rich.console import Console

    monkeypatch.setattr(
        "compd.cli.diagnose.console",
        lambda: Console(width=100, highlight=False, emoji=False, markup=False),
    )


def test_at_100_columns_no_cell_is_cut(case, capsys, terminal_100) -> None:
    """At 100 columns the table fits whole cells: signals and figures uncut, detail columns named under it."""
    code, out, err = run(capsys, "diagnose", *case)
    assert code == 0, err
    table = out[: out.index("residue disp_z_um")]
    assert all(len(line) <= 100 for line in table.splitlines())
    assert "…" not in table
    for name in ("spindle_power_kw", "T_coolant_degC", "feed_x_mm_per_min", "T_ambient_degC"):
        assert f"│ {name} " in table
    assert "│ 92.3 " in table and "│ yes " in table
    words = " ".join(table.split())
    assert "left out for width: sign, xcorr lag" in words and "--wide shows all" in words


def test_piped_output_takes_the_width_columns_asks_for(case, capsys, monkeypatch) -> None:
    """Piped with COLUMNS=120 exported, the table is at most 120 wide; --wide prints every column whole."""
    monkeypatch.setenv("COLUMNS", "120")
    code, out, err = run(capsys, "diagnose", *case)
    assert code == 0, err
    table = out[: out.index("residue disp_z_um")]
    assert max(len(line) for line in table.splitlines()) <= 120 and "…" not in table
    code, out, err = run(capsys, "diagnose", *case, "--wide")
    assert code == 0, err
    assert "|xcorr| / 99 % bound" in out and "left out for width" not in out
    assert "cutting process heat (power drawn by the cut, Horejs 2015)" in out
