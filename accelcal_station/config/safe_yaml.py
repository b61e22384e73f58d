"""YAML for configuration files that may be hostile: refused fast, in one line, when a file is
too large, nests too deep, expands aliases into too many nodes (a billion laughs) or
repeats a key (where PyYAML would silently keep the last one)."""
from __future__ import annotations

from collections.abc import Hashable
from typing import Any

import yaml

MAX_BYTES = 1 << 20  # a station config is a few kB; 1 MiB is far beyond any real one
MAX_DEPTH = 64
MAX_NODES = 100_000  # nodes after alias expansion


class HostileYAML(ValueError):
    """The document is refused; the message says why (without a file name)."""


class _Loader(yaml.SafeLoader):
    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        self._depth += 1
        if self._depth > MAX_DEPTH:
            mark = self.peek_event().start_mark
            raise HostileYAML(f"line {mark.line + 1}: nested more than {MAX_DEPTH} levels deep")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True) if key_node.tag != "tag:yaml.org,2002:merge" else None
            if key is not None:
                try:
                    dup = key in seen
                except TypeError:  # an unhashable key: PyYAML refuses it itself
                    continue
                if dup:
                    raise HostileYAML(f"line {key_node.start_mark.line + 1}: duplicate key {key!r}")
                seen.add(key)
        return super().construct_mapping(node, deep)


def _expanded_size(root: yaml.Node) -> int:
    """Nodes the document has once every alias is expanded (memoised: linear in the file)."""
    memo: dict[int, int] = {}
    order, stack = [], [root]
    while stack:  # iterative post-order: no recursion on deep documents
        n = stack.pop()
        if id(n) in memo:
            continue
        memo[id(n)] = -1
        order.append(n)
        kids = [c for pair in n.value for c in pair] if isinstance(n, yaml.MappingNode) else (
            n.value if isinstance(n, yaml.SequenceNode) else [])
        stack.extend(k for k in kids if id(k) not in memo)
    for n in reversed(order):
        kids = [c for pair in n.value for c in pair] if isinstance(n, yaml.MappingNode) else (
            n.value if isinstance(n, yaml.SequenceNode) else [])
        memo[id(n)] = min(MAX_NODES + 1, 1 + sum(max(memo.get(id(k), 0), 0) for k in kids))
    return memo[id(root)]


def _flow_depth(text: str) -> None:
    """Refuse deep [ { nesting before PyYAML's scanner (quadratic in flow depth) sees it."""
    depth = 0
    for ch in text:
        if ch in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                raise HostileYAML(f"nested more than {MAX_DEPTH} levels deep")
        elif ch in "]}" and depth:
            depth -= 1


def safe_load(text: str) -> Any:
    """Parse one YAML document with the limits above; raises HostileYAML or yaml.YAMLError."""
    if len(text.encode("utf-8", "surrogatepass")) > MAX_BYTES:
        raise HostileYAML(f"larger than {MAX_BYTES} bytes")
    _flow_depth(text)
    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        if root is None:
            return None
        if _expanded_size(root) > MAX_NODES:
            raise HostileYAML(f"aliases expand to more than {MAX_NODES} nodes (an alias bomb?)")
        return loader.construct_document(root)
    finally:
        loader.dispose()
