"""deploy/plc/FB_CompdOffset.st: well-formed structured text reading compd's status word and heartbeat as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from compd.service.loop.safety import HEARTBEAT_MODULO, Flag, Level

ST = Path(__file__).parents[2] / "deploy" / "plc" / "FB_CompdOffset.st"


def code() -> str:
    """The file without its (* comments *): what a compiler sees."""
    return re.sub(r"\(\*.*?\*\)", " ", ST.read_text(), flags=re.S)


def words(text: str) -> list[str]:
    return re.findall(r"[A-Za-z_][A-Za-z_0-9]*", text.upper())


def test_blocks_are_balanced():
    """FUNCTION_BLOCK, VAR sections and IF statements each close, in order."""
    stack: list[str] = []
    closing = {
        "END_FUNCTION_BLOCK": "FUNCTION_BLOCK",
        "END_VAR": "VAR",
        "END_IF": "IF",
    }
    for word in words(code()):
        if word in ("FUNCTION_BLOCK", "IF") or word.startswith("VAR"):
            stack.append("VAR" if word.startswith("VAR") else word)
        elif word in closing:
            assert stack and stack.pop() == closing[word], f"{word} closes nothing open"
    assert stack == []


def test_status_bits_and_heartbeat_are_compds():
    """The masks in the code are compd's: level in bits 0-1, STOPPED bit 5; the heartbeat fits an INT."""
    text = code()
    assert "dwStatus AND 16#3)" in text and Level.FAULTED == 2
    assert f"dwStatus AND 16#{int(Flag.STOPPED):X})" in text
    assert HEARTBEAT_MODULO - 1 == 32767  # the largest INT: iHeartbeat : INT holds every count
    assert re.search(r"iHeartbeat\s*:\s*INT;", text)


def test_a_structured_text_parser_accepts_it():
    """blark (an IEC 61131-3 structured-text grammar, TwinCAT dialect) parses the file without error."""
    parse = pytest.importorskip(
        "blark.parse", reason="blark missing: pip install -e '.[test]' installs it"
    )
    result = parse.parse_source_code(ST.read_text(), fn=str(ST))
    assert result.exception is None, result.exception
