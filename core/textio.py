"""Reading the text files of the datasets, with every failure an InputError naming the file.

Calibration, timestamps, CSV lists, YAML and JSON headers all come through :func:`read_text`
(or :func:`read_json_object`): a missing file, a folder where a file should be, a file that cannot be
read (permissions, I/O error) or bytes that are not UTF-8 become one line naming the file, never a
traceback.

Parsing is bounded, so a small hostile file cannot take the time, memory or stack of the machine:

- JSON (:func:`loads_json`, used by :func:`read_json_object`): at most :data:`JSON_MAX_BYTES` of text and
  :data:`JSON_MAX_DEPTH` levels of nesting, checked by a linear scan before the parser runs (Python's
  parser recurses once per level: 50,000 nested brackets would end in a RecursionError).
- YAML (:func:`loads_yaml`): PyYAML's safe loader (plain data only, no Python objects), at most
  :data:`YAML_MAX_BYTES` of text, at most :data:`YAML_MAX_ALIASES` alias uses (``*name``) and at most
  :data:`YAML_MAX_EXPANDED_NODES` values with the aliases expanded (a "billion laughs" document of a few
  hundred bytes expands to 10^9 values through nested aliases; it is refused after composing its small
  graph, before anything walks it), no recursive alias and no key twice in one mapping (PyYAML would
  silently keep the last).
- Values quoted in messages go through :func:`short` (at most ~80 characters), never a whole value.
"""
from __future__ import annotations

import json
import re
import reprlib
from pathlib import Path

import yaml

from deepslam.core.errors import InputError

JSON_MAX_BYTES = 64 * 1024 * 1024
"""Largest JSON document parsed (characters); sequence headers and records are kilobytes."""
JSON_MAX_DEPTH = 100
"""Deepest nesting of arrays/objects accepted in a JSON document (this project writes at most ~10)."""
YAML_MAX_BYTES = 1_000_000
"""Largest YAML document parsed (characters); a sensor.yaml or scene file is a few kilobytes."""
YAML_MAX_ALIASES = 100
"""Most alias uses (``*name``) accepted in one YAML document."""
YAML_MAX_EXPANDED_NODES = 1_000_000
"""Most values a YAML document may hold with every alias expanded (a few dozen aliases nested nine deep
already make 10^9: the classic "billion laughs")."""
SHORT_CHARS = 80
"""Longest quoted value in a message (:func:`short`)."""


def short(value, limit: int = SHORT_CHARS) -> str:
    """``repr(value)`` of at most ``limit`` characters (``...`` marks a cut). Nested containers are
    printed a few levels and items deep only (:mod:`reprlib`), so a huge or alias-shared value is never
    walked whole."""
    r = reprlib.Repr()
    r.maxlevel = 3
    r.maxdict = r.maxlist = r.maxtuple = r.maxset = r.maxfrozenset = r.maxdeque = r.maxarray = 8
    r.maxstring = r.maxlong = r.maxother = limit
    text = r.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_text(path: str | Path, what: str = "file") -> str:
    """UTF-8 text of ``path`` (a BOM is dropped).

    Args:
        path: the file.
        what: what the file is, for the messages (e.g. ``"calibration file"``).
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(p, f"is a folder, expected a {what}")
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise InputError(p, f"{what} is missing") from None
    except OSError as e:
        raise InputError(p, f"cannot read the {what} ({e.strerror or e})") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise InputError(p, f"not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start})", line=line) from None


def read_json_object(path: str | Path, what: str = "JSON file") -> dict:
    """The JSON object in ``path``; InputError for unreadable text, invalid JSON or a non-object."""
    p = Path(path)
    doc = loads_json(read_text(p, what), p, what)
    if not isinstance(doc, dict):
        raise InputError(p, f"expected a JSON object, got {type(doc).__name__}")
    return doc


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*+"', re.S)
_JSON_BRACKETS = re.compile(r"[\[\]{}]")


def json_depth(text: str) -> int:
    """Deepest bracket nesting of a JSON text, by a linear scan that skips string literals (no recursion,
    no parsing: malformed text gives some number and the parser then reports the fault)."""
    depth = deepest = 0
    for m in _JSON_BRACKETS.finditer(_JSON_STRING.sub('""', text)):
        if m.group() in "[{":
            depth += 1
            if depth > deepest:
                deepest = depth
        else:
            depth -= 1
    return deepest


def loads_json(text: str | bytes, path: str | Path | None, what: str = "JSON",
               max_depth: int = JSON_MAX_DEPTH, max_bytes: int = JSON_MAX_BYTES):
    """``json.loads(text)`` within bounds: InputError naming ``path`` for text over ``max_bytes``, nesting
    deeper than ``max_depth`` or invalid JSON (with its line)."""
    if isinstance(text, (bytes, bytearray)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as e:
            raise InputError(path, f"{what} is not UTF-8 (byte {e.start})") from None
    if len(text) > max_bytes:
        raise InputError(path, f"{what} is too large ({len(text)} characters; at most {max_bytes})")
    if "[" in text or "{" in text:
        deepest = json_depth(text)
        if deepest > max_depth:
            raise InputError(path, f"{what} is nested too deeply ({deepest} levels; at most {max_depth})")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(path, f"{what} is not valid JSON ({e.msg})", line=e.lineno) from None
    except RecursionError:
        raise InputError(path, f"{what} is nested too deeply") from None


def loads_yaml(text: str, path: str | Path | None, what: str = "YAML file", line_offset: int = 0,
               max_aliases: int = YAML_MAX_ALIASES, max_bytes: int = YAML_MAX_BYTES):
    """The data of one YAML document, safely and within bounds (see the module docstring).

    Args:
        text: the document.
        path: the file, for messages.
        what: what the file is, for messages.
        line_offset: lines removed from the top of the file before ``text`` (for the line numbers).

    Raises:
        InputError: naming ``path`` (and the line where known) for text over ``max_bytes``, more than
            ``max_aliases`` alias uses, a key given twice in one mapping, or text that is not YAML.
    """
    if len(text) > max_bytes:
        raise InputError(path, f"{what} is too large ({len(text)} characters; at most {max_bytes})")
    loader = _bounded_loader(yaml)(text)
    loader.max_aliases = max_aliases
    try:
        return loader.get_single_data()
    except _YamlRefused as e:
        raise InputError(path, f"{what}: {e.what}", line=None if e.line is None else e.line + 1 + line_offset) from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line = getattr(mark, "line", None)
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise InputError(path, f"{what} is not valid YAML ({short(problem)})",
                         line=None if line is None else line + 1 + line_offset) from None
    except RecursionError:
        raise InputError(path, f"{what} is nested too deeply") from None
    finally:
        loader.dispose()


class _YamlRefused(Exception):
    def __init__(self, what: str, line: int | None):
        super().__init__(what)
        self.what, self.line = what, line


_LOADER = None


def _bounded_loader(yaml):
    """PyYAML's SafeLoader counting alias uses and refusing duplicate keys (built once, lazily, so that
    importing this module does not import yaml)."""
    global _LOADER
    if _LOADER is not None:
        return _LOADER

    class BoundedSafeLoader(yaml.SafeLoader):
        max_aliases = YAML_MAX_ALIASES
        aliases_used = 0

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                self.aliases_used += 1
                if self.aliases_used > self.max_aliases:
                    mark = self.peek_event().start_mark
                    raise _YamlRefused(f"more than {self.max_aliases} aliases (*name); refused as a possible "
                                       "alias bomb", getattr(mark, "line", None))
            return super().compose_node(parent, index)

        def get_single_node(self):
            node = super().get_single_node()
            if node is not None:
                _check_expansion(yaml, node)
            return node

        def construct_mapping(self, node, deep=False):
            if isinstance(node, yaml.MappingNode):
                seen = set()
                for key_node, _ in node.value:
                    if isinstance(key_node, yaml.ScalarNode):
                        key = (key_node.tag, key_node.value)
                        if key in seen and key_node.value != "<<":
                            raise _YamlRefused(f"key {short(key_node.value)} is given twice in one mapping",
                                               key_node.start_mark.line)
                        seen.add(key)
            return super().construct_mapping(node, deep=deep)

    _LOADER = BoundedSafeLoader
    return _LOADER


def _check_expansion(yaml, root) -> None:
    """_YamlRefused when the node graph (aliases share nodes) holds a cycle or expands to more than
    YAML_MAX_EXPANDED_NODES values; linear in the graph's size (memoised, no recursion)."""
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            on_path.discard(key)
            kids = _children(yaml, node)
            total = 1 + sum(size[id(k)] for k in kids)
            if total > YAML_MAX_EXPANDED_NODES:
                raise _YamlRefused(f"expands to more than {YAML_MAX_EXPANDED_NODES} values through its aliases; "
                                   "refused as an alias bomb", node.start_mark.line)
            size[key] = total
            continue
        if key in size:
            continue
        if key in on_path:
            raise _YamlRefused("a recursive alias (a value that contains itself)", node.start_mark.line)
        on_path.add(key)
        stack.append((node, True))
        for k in _children(yaml, node):
            if id(k) in on_path:
                raise _YamlRefused("a recursive alias (a value that contains itself)", k.start_mark.line)
            if id(k) not in size:
                stack.append((k, False))


def _children(yaml, node) -> list:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []
