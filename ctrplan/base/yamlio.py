"""YAML loading that remembers where every key came from, so errors can name the line; and the
writing of the files ctrplan generates (scenes, robots)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ctrplan.base.errors import InputError

KeyPath = tuple[str | int, ...]


class _Loader(yaml.SafeLoader):
    """`yaml.SafeLoader` that also reads YAML 1.2 floats whose exponent has no sign or whose mantissa
    has no dot (``5e1``, ``1.0e308``, ``1e-3``): YAML 1.1 reads them as strings."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)[eE][-+]?[0-9]+$"),
    list("-+.0123456789"))


@dataclass(frozen=True)
class YamlDoc:
    """A parsed YAML mapping plus the 1-based line of every key path, for error messages."""

    data: dict[str, Any]
    path: Path
    lines: dict[KeyPath, int]

    def where(self, keys: KeyPath) -> str:
        """``file:line: a.b[2].c`` for the deepest known prefix of ``keys``."""
        line = None
        for n in range(len(keys), -1, -1):
            line = self.lines.get(tuple(keys[:n]))
            if line is not None:
                break
        name = "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in keys).lstrip(".")
        loc = f"{self.path}:{line}" if line is not None else str(self.path)
        return f"{loc}: {name}" if name else loc

    def error(self, keys: KeyPath, message: str) -> InputError:
        return InputError(f"{self.where(keys)}: {message}")


def _walk(node: yaml.Node, prefix: KeyPath, lines: dict[KeyPath, int], path: Path) -> None:
    lines.setdefault(prefix, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        seen: set[KeyPath] = set()
        for key_node, value_node in node.value:
            key = prefix + (str(key_node.value),)
            line = key_node.start_mark.line + 1
            if key in seen:  # YAML forbids it; PyYAML would silently keep the last value
                name = ".".join(str(k) for k in key)
                raise InputError(f"{path}:{line}: {name}: duplicate key (first on line {lines[key]})")
            seen.add(key)
            lines[key] = line
            _walk(value_node, key, lines, path)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _walk(item, prefix + (i,), lines, path)


class _FlowListDumper(yaml.SafeDumper):
    """Lists of numbers (and of lists of numbers) in flow style ([x, y, z]); everything else in block
    style; no anchors and aliases (a value used twice is written twice)."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(v, (int, float)) for v in data) or \
        all(isinstance(v, list) and all(isinstance(u, (int, float)) for u in v) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow and len(data) > 0)


_FlowListDumper.add_representer(list, _represent_list)


def dump_yaml(data: dict[str, Any], width: int = 110) -> str:
    """YAML text of a mapping, keys in their order, vectors and matrices on one line each."""
    return yaml.dump(data, Dumper=_FlowListDumper, sort_keys=False, width=width)


def load_yaml(path: str | Path) -> YamlDoc:
    """Load a YAML mapping; raise `InputError` naming the file (and line) on any problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    try:
        node = yaml.compose(text, Loader=_Loader)
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        loc = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{loc}: malformed YAML ({problem})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a YAML mapping at the top level")
    lines: dict[KeyPath, int] = {}
    _walk(node, (), lines, path)
    return YamlDoc(data=data, path=path, lines=lines)
