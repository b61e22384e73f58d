"""YAML for configuration files that may be hostile: refused fast, in one line, when a file is
too large, nests too deep, expands aliases into too many nodes (a billion laughs),
repeats a key (where PyYAML would silently keep the last one), or holds an integer
longer than any number a float can hold.

Numbers are read without YAML 1.1's base-60 form (``1:30:00``; YAML 1.2 dropped it):
such a scalar is a string, so ``1:0:0:...`` costs nothing (PyYAML's base-60 integer is
quadratic in its length), and an explicit ``!!int 1:0:0`` is refused.
"""
from __future__ import annotations

import re
from collections.abc import Hashable
from typing import Any

import yaml

MAX_BYTES = 1 << 20  # a station config is a few kB; 1 MiB is far beyond any real one
MAX_DEPTH = 64
MAX_NODES = 100_000  # nodes after alias expansion
MAX_INT_DIGITS = 300  # beyond 1e308 an integer is no float, and no config value
_INT = re.compile(r"^(?:[-+]?0b[0-1_]+|[-+]?0[0-7_]+|[-+]?(?:0|[1-9][0-9_]*)|[-+]?0x[0-9a-fA-F_]+)$")
_FLOAT = re.compile(r"^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+][0-9]+)?|\.[0-9][0-9_]*(?:[eE][-+][0-9]+)?"
                    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")


def _resolvers_without_base60() -> dict[Any, list[tuple[str, re.Pattern[str]]]]:
    """PyYAML's safe implicit resolvers with the int and float patterns minus their base-60 forms."""
    swap = {"tag:yaml.org,2002:int": _INT, "tag:yaml.org,2002:float": _FLOAT}
    return {first: [(tag, swap.get(tag, rx)) for tag, rx in rules]
            for first, rules in yaml.SafeLoader.yaml_implicit_resolvers.items()}


class HostileYAML(ValueError):
    """The document is refused; the message says why (without a file name)."""


class _Loader(yaml.SafeLoader):
    yaml_implicit_resolvers = _resolvers_without_base60()

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


def _construct_int(loader: _Loader, node: yaml.ScalarNode) -> int:
    """An integer scalar: no base-60 form, no more than MAX_INT_DIGITS digits (refused before converting)."""
    text = str(node.value)
    if ":" in text:
        raise HostileYAML(f"line {node.start_mark.line + 1}: base-60 integer {text[:20]!r}...; write the number "
                          "in decimal")
    if len(text) > MAX_INT_DIGITS:
        raise HostileYAML(f"line {node.start_mark.line + 1}: an integer of {len(text)} digits; allowed: at most "
                          f"{MAX_INT_DIGITS}")
    return int(yaml.SafeLoader.construct_yaml_int(loader, node))


def _construct_float(loader: _Loader, node: yaml.ScalarNode) -> float:
    """A float scalar without the base-60 form."""
    if ":" in str(node.value):
        raise HostileYAML(f"line {node.start_mark.line + 1}: base-60 number {str(node.value)[:20]!r}...; write it "
                          "in decimal")
    return float(yaml.SafeLoader.construct_yaml_float(loader, node))


_Loader.add_constructor("tag:yaml.org,2002:int", _construct_int)
_Loader.add_constructor("tag:yaml.org,2002:float", _construct_float)


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
    except (ValueError, OverflowError, RecursionError) as e:  # e.g. a timestamp 2024-02-30, a date past 9999
        if isinstance(e, HostileYAML):
            raise
        raise HostileYAML(f"a value that cannot be read ({str(e)[:80]})") from None
    finally:
        loader.dispose()
