"""YAML read with bounds: file size, nesting depth and what aliases expand to.

A YAML alias (``*name``) repeats an anchored node without copying it in the file, so nine lines of
nested aliases (the "billion laughs" file) describe 10^9 values: ``yaml.safe_load`` would build
them all, and whatever serialises the config later (recording metadata, run directories) would
write them all. The node graph is composed first (aliases are shared nodes there, so that is
cheap), its expanded size is counted with each shared node counted once per use, and only a
document within the limits is constructed into Python values.

Before construction every scalar and mapping is checked too: an integer of thousands of digits
(Python refuses to convert it, with a ValueError) and a key given twice in one mapping (YAML would
keep the last one silently) are ConfigErrors naming the line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from yaml.events import AliasEvent, CollectionEndEvent, CollectionStartEvent
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from bridge.errors import ConfigError

MAX_FILE_BYTES = 256 << 10  # experiment files are a few KB; long tables belong in a csv: profile
MAX_ALIAS_GROWTH = 100_000  # values plus characters that aliases may add to what the file spells out
MAX_DEPTH = 100  # nesting levels; the parser and pydantic recurse once per level
MAX_INT_DIGITS = 30  # an int64 has 19 digits; seeds, counts and step numbers fit easily
_INT_TAG = "tag:yaml.org,2002:int"
_MERGE_TAG = "tag:yaml.org,2002:merge"


# libyaml's parser where it is installed (ten times faster); it composes recursively in C, so the
# nesting depth is checked on its (iterative) event stream first: a deep file would crash it
_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def read_yaml(file: Path) -> Any:
    """The data of the YAML file ``file``, or a ConfigError naming the file and what is wrong."""
    try:
        size = file.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ConfigError(
                f"experiment file is {size} bytes; the limit is {MAX_FILE_BYTES} (experiment files "
                f"are a few KB: is this the right file?) [{file}]"
            )
        text = file.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read experiment file: {exc.strerror} [{file}]") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"experiment file is not UTF-8 text ({exc.reason} at byte {exc.start}) [{file}]"
        ) from exc
    return parse_yaml(text, file)


def parse_yaml(text: str, file: Path | str = "<text>") -> Any:
    """Parse ``text`` with the bounds of :func:`read_yaml` (``file`` only names it in errors)."""
    has_aliases = _check_depth(text, file)
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if has_aliases:
            _check_size(node, file)
        _check_scalars(node, file)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{file}: not valid YAML: {exc}") from exc
    except RecursionError:
        raise ConfigError(
            f"{file}: the YAML nests too deeply to read; experiment files need a few levels, "
            f"at most {MAX_DEPTH} are accepted"
        ) from None
    finally:
        loader.dispose()


def _check_depth(text: str, file: Path | str, loader_class: Any = _Loader) -> bool:
    """Raise if collections nest more than MAX_DEPTH deep; whether ``text`` has aliases.

    A YAML syntax error is left for the composer to report. libyaml scans a flow collection's
    tokens ahead to its own nesting limit (1000 levels in newer releases) before the first event,
    so a deeper file fails there with libyaml's wording; it is scanned again with PyYAML's own
    (iterative, 1024-character lookahead) loader, so the limit and its message are always ours.
    """
    loader = loader_class(text)
    depth, aliases = 0, False
    try:
        while loader.check_event():
            event = loader.get_event()
            if isinstance(event, CollectionStartEvent):
                depth += 1
                if depth > MAX_DEPTH:
                    line = event.start_mark.line + 1 if event.start_mark else "?"
                    raise ConfigError(
                        f"{file}: line {line}: nested more than {MAX_DEPTH} levels "
                        "deep; experiment files need a few levels"
                    )
            elif isinstance(event, CollectionEndEvent):
                depth -= 1
            elif isinstance(event, AliasEvent):
                aliases = True
    except yaml.YAMLError:
        if loader_class is not yaml.SafeLoader:
            return _check_depth(text, file, yaml.SafeLoader)
        return True
    finally:
        loader.dispose()
    return aliases


def _check_size(root: Node, file: Path | str) -> None:
    """Raise unless aliases grow ``root`` by at most MAX_ALIAS_GROWTH and it nests at most MAX_DEPTH."""
    sizes: dict[int, tuple[int, int]] = {}  # id(node) -> (expanded size, height): shared nodes once
    on_path: set[int] = set()
    literal: list[int] = []  # the size of each node as written, each once

    def measure(node: Node, depth: int) -> tuple[int, int]:
        key = id(node)
        if key in on_path:
            raise ConfigError(
                f"{file}: line {node.start_mark.line + 1}: an alias refers to a node that contains "
                "it (a recursive structure); experiment files are trees"
            )
        size, height = sizes.get(key, (0, 0))
        if depth + height > MAX_DEPTH:
            raise ConfigError(
                f"{file}: line {node.start_mark.line + 1}: nested more than {MAX_DEPTH} levels deep; "
                "experiment files need a few levels"
            )
        if key in sizes:
            return size, height
        on_path.add(key)
        children = [measure(child, depth + 1) for child in _children(node)]
        on_path.discard(key)
        own = len(str(node.value)) if isinstance(node, ScalarNode) else 0
        size = 1 + own + sum(s for s, _ in children)
        height = 1 + max((h for _, h in children), default=0)
        sizes[key] = size, height
        literal.append(1 + own)
        return size, height

    expanded, _ = measure(root, 0)
    if expanded - sum(literal) > MAX_ALIAS_GROWTH:
        raise ConfigError(
            f"{file}: aliases (*name) repeating anchors (&name) expand this YAML to {expanded:,} values "
            f"and characters, {sum(literal):,} written out; aliases may add at most "
            f"{MAX_ALIAS_GROWTH:,}: write the values out, or use fewer nested aliases"
        )


def _check_scalars(root: Node, file: Path | str) -> None:
    """Raise on an integer of more than MAX_INT_DIGITS digits or a key given twice in one mapping."""
    seen: set[int] = set()
    stack = [root]
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        line = node.start_mark.line + 1
        if isinstance(node, ScalarNode) and node.tag == _INT_TAG:
            digits = sum(c.isdigit() for c in str(node.value))
            if digits > MAX_INT_DIGITS:
                raise ConfigError(
                    f"{file}: line {line}: an integer of {digits} digits; at most {MAX_INT_DIGITS} are "
                    "accepted (seeds, counts and steps need far fewer): is a value mistyped?"
                )
        if isinstance(node, MappingNode):
            _check_keys(node, file)
        stack.extend(_children(node))


def _check_keys(node: MappingNode, file: Path | str) -> None:
    first: dict[str, int] = {}
    for key, _ in node.value:
        if not isinstance(key, ScalarNode) or key.tag == _MERGE_TAG:
            continue  # a merge key (<<) may override; complex keys are refused later by the schema
        line = key.start_mark.line + 1
        text = str(key.value)
        if text in first:
            raise ConfigError(
                f"{file}: line {line}: key {text!r} is given twice in one mapping (first at line "
                f"{first[text]}); YAML would keep only the last one: remove or rename one of them"
            )
        first[text] = line


def _children(node: Node) -> list[Node]:
    if isinstance(node, SequenceNode):
        return list(node.value)
    if isinstance(node, MappingNode):
        return [part for pair in node.value for part in pair]
    return []
