"""Reading a sweep YAML strictly: a key given twice in one mapping and an empty file are errors
(plain `yaml.safe_load` keeps the last duplicate and reads an empty file as no settings)."""

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


def _compose_with_parents(loader):
    root = yaml.SafeLoader.get_single_node(loader)
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
