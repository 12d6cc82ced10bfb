"""Reading a sweep YAML strictly: a key given twice in one mapping and an empty file are errors
(plain `yaml.safe_load` keeps the last duplicate and reads an empty file as no settings), and so
are documents that aliases blow up (`&a` / `*a` nested: more than MAX_NODES nodes once expanded,
or deeper than MAX_DEPTH) and values of YAML types a sweep has no use for (dates, binary, sets,
ordered maps): each one named by its key, before anything is built from it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from mjxrow.rollout.config import ConfigError


class _UniqueKeyLoader(yaml.SafeLoader):
    """yaml.SafeLoader that rejects a key given twice in one mapping (plain YAML keeps the last
    one silently)."""

    path: list[str] = []


def _construct_mapping(loader, node, deep=False):
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in seen:
            where = _mapping_path(loader, node)
            raise ConfigError(f"{where}{key}: duplicate key (lines {seen[key] + 1} and "
                              f"{key_node.start_mark.line + 1})")
        seen[key] = key_node.start_mark.line
    return yaml.SafeLoader.construct_mapping(loader, node, deep)


def _mapping_path(loader, node) -> str:
    """The dotted path of a mapping node inside the document ('' at the top, 'field.' ...)."""
    parents = getattr(loader, "_parents", {})
    parts = []
    while id(node) in parents:
        node, key = parents[id(node)]
        parts.append(str(key))
    return "".join(f"{p}." for p in reversed(parts))


MAX_NODES = 100_000  # nodes of the document with its aliases expanded
MAX_DEPTH = 32  # nesting of mappings and lists
_SCALARS = {f"tag:yaml.org,2002:{t}" for t in ("str", "int", "float", "bool", "null")}
_KINDS = {"timestamp": "a date or time", "binary": "binary data", "set": "a set",
          "omap": "an ordered map", "pairs": "a list of pairs"}


def _check_nodes(root) -> None:
    """ConfigError naming the key where the document, its aliases expanded, passes MAX_NODES
    nodes or MAX_DEPTH levels, or holds a value of a type other than a mapping, a list, a
    string, a number, true / false or null. Stops at the budget: a bomb costs little."""
    stack = [(root, "", 0)]
    count = 0
    while stack:
        node, path, depth = stack.pop()
        count += 1
        where = path or "the document"
        top = path.split(".")[0].split("[")[0] or "the document"  # the top-level key
        if count > MAX_NODES:
            raise ConfigError(f"{top}: more than {MAX_NODES:,} values once its aliases (*) are "
                              "expanded; write the values out or use a range")
        if depth > MAX_DEPTH:
            raise ConfigError(f"{top}: nested more than {MAX_DEPTH} levels deep")
        tag = node.tag.rsplit(":", 1)[-1]
        if isinstance(node, yaml.MappingNode) and node.tag == yaml.resolver.BaseResolver.\
                DEFAULT_MAPPING_TAG:
            stack += [(v, f"{path}.{k.value}" if path else str(k.value), depth + 1)
                      for k, v in node.value]
        elif isinstance(node, yaml.SequenceNode) and node.tag == yaml.resolver.BaseResolver.\
                DEFAULT_SEQUENCE_TAG:
            stack += [(v, f"{path}[{i}]", depth + 1) for i, v in enumerate(node.value)]
        elif not (isinstance(node, yaml.ScalarNode) and node.tag in _SCALARS):
            kind = _KINDS.get(tag, f"a value tagged {node.tag}")
            raise ConfigError(f"{where}: {kind} is not a value a sweep takes; quote it if it "
                              "is a name")


def _compose_with_parents(loader):
    root = yaml.SafeLoader.get_single_node(loader)
    if root is not None:
        _check_nodes(root)
    parents: dict[int, tuple[Any, Any]] = {}
    stack = [root] if root is not None else []
    while stack:
        n = stack.pop()
        if isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                if isinstance(v, yaml.MappingNode):
                    parents[id(v)] = (n, k.value)
                    stack.append(v)
    loader._parents = parents
    return root


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
                                 _construct_mapping)
_UniqueKeyLoader.get_single_node = _compose_with_parents


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file, rejecting duplicate keys and an empty file; ConfigError naming the
    file (and line) or the key."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file") from None
    try:
        raw = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f":{mark.line + 1}" if mark else ""
        raise ConfigError(f"{path}{where}: invalid YAML ({getattr(e, 'problem', e)})") from None
    if raw is None:
        raise ConfigError(f"{path}: empty file; a sweep YAML needs at least one key "
                          "(sweeps.yaml is an example)")
    return raw
