"""A message judged from its bytes before a parse: nesting depth, the request id, numbers compd does not read."""

from __future__ import annotations

import asyncio
import json

import pytest

from compd.errors import CompdError
from compd.service.fleet.wirecheck import (
    MAX_DEPTH,
    Parser,
    cheap_request_id,
    nesting_depth,
    parse_checked,
    record_or_none,
)


@pytest.mark.parametrize(
    ("text", "depth"),
    [
        ("{}", 1),
        ('{"a": [1, {"b": []}]}', 4),
        ('{"a": "[[[[{{{{"}', 1),  # brackets inside a string are text
        (r'{"a": "\"[[[", "b": [[]]}', 3),  # an escaped quote does not end the string
        ("1", 0),
    ],
)
def test_the_nesting_depth_counts_brackets_outside_strings(text: str, depth: int):
    """Depth is the deepest run of [ and { outside JSON strings, escapes honoured."""
    assert nesting_depth(text.encode()) == depth
    assert nesting_depth(text.encode()) == _parsed_depth(json.loads(text))


def _parsed_depth(value: object) -> int:
    if isinstance(value, dict):
        return 1 + max((_parsed_depth(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return 1 + max((_parsed_depth(v) for v in value), default=0)
    return 0


def test_a_payload_nested_past_the_bound_is_refused_before_it_is_parsed():
    """MAX_DEPTH + 1 levels are refused naming the bound; a million "[" is refused the same way."""
    deep = b'{"request_id": "r1", "a": ' + b"[" * MAX_DEPTH + b"]" * MAX_DEPTH + b"}"
    for payload in (deep, b"[" * 1_000_000):
        with pytest.raises(CompdError, match=f"nested more than {MAX_DEPTH} deep"):
            parse_checked(payload)


@pytest.mark.parametrize(
    ("payload", "request_id"),
    [
        (b'{"request_id": "cmm-0412", "x": 1}', "cmm-0412"),
        (b'{"x": "' + b"A" * 100_000 + b'", "request_id" : "r-9"}', "r-9"),
        (b'{"request_id": "r1", "n": "\\"request_id\\": \\"r2\\""}', "r1"),  # text, not a key
        (b'{"request_id": "r1", "n": {"request_id": "r2"}}', None),  # named twice
        (b'{"request_id": "a/b"}', None),  # not a topic level
        (b"not json at all", None),
    ],
)
def test_the_request_id_is_read_from_the_bytes_only_where_it_is_unambiguous(
    payload: bytes, request_id: str | None
):
    """cheap_request_id answers an id named once and valid as a topic level, else None."""
    assert cheap_request_id(payload) == request_id


def test_a_number_compd_does_not_read_is_found_with_its_place():
    """NaN, 1e400 or a 31-digit integer anywhere in the request is named by its path."""
    parsed = parse_checked(b'{"a": {"b": [1, 2, {"c": 1e400}]}, "d": 3}')
    assert parsed.unread == "a.b[2].c: 1e400 (beyond any float)"
    assert parse_checked(b'{"a": [1, 2.5, "x", null, true]}').unread is None
    assert parse_checked(b'{"n": ' + b"9" * 31 + b"}").unread == "n: an integer of 31 digits"


def test_a_large_array_is_parsed_whole_in_a_worker_thread():
    """A 1.4 MB array of numbers parses off the loop to every element, none unread."""
    payload = b'{"request_id": "r1", "junk": [' + b",".join([b"1"] * 700_000) + b"]}"
    parsed = asyncio.run(Parser().parse(payload))
    assert len(parsed.value["junk"]) == 700_000 and parsed.unread is None


def test_a_retained_record_over_its_bound_or_too_deep_is_not_read():
    """record_or_none gives None past the size or depth bound, or for bytes that are not JSON."""
    assert record_or_none(b'{"a": 1}', max_bytes=100) == {"a": 1}
    assert record_or_none(b'{"a": "' + b"x" * 100 + b'"}', max_bytes=100) is None
    assert record_or_none(b"[" * 50 + b"]" * 50, max_bytes=1000) is None
    assert record_or_none(b"{", max_bytes=100) is None
