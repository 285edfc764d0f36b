"""A YAML document built from the parser's events, without its node tree: what keeps loading small.

PyYAML builds a document by composing its whole node tree first (a node and
two marks per value, about 0.4 kB each), then constructing the values from
it. A model file's consistency model holds a 60 x 60 covariance: 1.4 MB of
nodes for 29 kB of numbers, and a daemon keeps the memory they took (Python
seldom hands freed memory back to the system). :func:`build` constructs each
value as its event arrives, with the loader's own resolver and constructors
(the same tags, the same values), and gives up on what only the composer
handles: anchors and aliases, merge keys, explicit tags on collections, other
than the plain scalar types, several documents. The caller then composes the
node tree as before (:func:`compd.files.yamlplace.parse_yaml`), so a document
means the same either way; only where an error needs its line is the node
tree composed (:class:`compd.files.yamlplace.NodeTree`).
"""

from __future__ import annotations

from typing import Any, cast

import yaml

#: The scalar types built here, each by the safe constructor's own function for its tag.
SCALAR_TAGS = frozenset(
    f"tag:yaml.org,2002:{name}" for name in ("null", "bool", "int", "float", "str", "timestamp")
)
_SEQUENCE = "tag:yaml.org,2002:seq"
_MAPPING = "tag:yaml.org,2002:map"


class _GiveUp(Exception):
    """The document needs what only composing its node tree handles."""


class _NoKey:
    """A mapping waiting for its next key (a key may be ``None``: ``~: 1``)."""


_NO_KEY = _NoKey()


class _Open:
    """A list or mapping whose end event has not come yet."""

    __slots__ = ("key", "value")

    def __init__(self, value: list[Any] | dict[Any, Any]) -> None:
        self.value = value
        self.key: Any = _NO_KEY

    def add(self, item: Any) -> None:
        if isinstance(self.value, list):
            self.value.append(item)
        elif self.key is _NO_KEY:
            try:
                hash(item)
            except TypeError:
                raise _GiveUp from None  # the composer's path words the error (unhashable key)
            self.key = item
        else:
            self.value[self.key] = item
            self.key = _NO_KEY


def build(text: str, loader_type: Any) -> tuple[bool, Any]:
    """``(True, document)`` built from ``text``'s events, or ``(False, None)``: compose it instead.

    ``loader_type`` is the loader the node tree would be composed with
    (``yaml.CSafeLoader``). A syntax error raises ``yaml.YAMLError`` as composing
    does; a scalar its constructor refuses, ``ValueError`` or ``OverflowError``.
    """
    loader = loader_type(text)
    try:
        return True, _document(loader)
    except _GiveUp:
        return False, None
    finally:
        loader.dispose()


def _document(loader: Any) -> Any:
    document: Any = None
    documents = 0
    stack: list[_Open] = []
    while loader.check_event():
        event = loader.get_event()
        if isinstance(event, yaml.DocumentStartEvent):
            documents += 1
            if documents > 1:
                raise _GiveUp  # the composer refuses a second document, with its place
            continue
        if isinstance(event, yaml.StreamStartEvent | yaml.StreamEndEvent | yaml.DocumentEndEvent):
            continue
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            raise _GiveUp
        if isinstance(event, yaml.ScalarEvent):
            value = _scalar(loader, event)
        elif isinstance(event, yaml.SequenceStartEvent):
            _check_tag(loader, yaml.SequenceNode, event, _SEQUENCE)
            stack.append(_Open([]))
            continue
        elif isinstance(event, yaml.MappingStartEvent):
            _check_tag(loader, yaml.MappingNode, event, _MAPPING)
            stack.append(_Open({}))
            continue
        elif isinstance(event, yaml.CollectionEndEvent):
            value = stack.pop().value
        else:
            raise _GiveUp
        if stack:
            stack[-1].add(value)
        else:
            document = value
    return document


def _scalar(loader: Any, event: yaml.ScalarEvent) -> Any:
    """The value of one scalar, as the composer resolves its tag and the constructor builds it."""
    tag = event.tag
    if tag is None or tag == "!":
        tag = loader.resolve(yaml.ScalarNode, event.value, event.implicit)
    if tag not in SCALAR_TAGS:
        raise _GiveUp  # a merge key ('<<'), !!binary, a tag of the file's own
    # libyaml's events carry its own Mark type, with the same line and column: what an error reads.
    start, end = cast(yaml.Mark, event.start_mark), cast(yaml.Mark, event.end_mark)
    node = yaml.ScalarNode(tag, event.value, start, end, event.style)
    return loader.yaml_constructors[tag](loader, node)


def _check_tag(
    loader: Any, kind: type[yaml.Node], event: yaml.CollectionStartEvent, plain: str
) -> None:
    """Only a plain list or mapping is built here (``!!set``, ``!!omap``... are composed)."""
    tag = event.tag
    if tag is None or tag == "!":
        tag = loader.resolve(kind, None, event.implicit)
    if tag != plain:
        raise _GiveUp
