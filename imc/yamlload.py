"""A strict YAML reader for scenario files: every problem is one line with its line and column.

On top of PyYAML's safe loader it refuses duplicate keys (the last one would silently win),
tags other than YAML's plain ones (``!!str``, ``!!int``, ``!!float``, ``!!bool``, ``!!null``,
``!!timestamp``, ``!!seq``, ``!!map``), nesting deeper than :data:`MAX_DEPTH`, documents whose
anchors and aliases expand to more than :data:`MAX_VALUES` values (and recursive aliases),
files over :data:`MAX_BYTES`, and turns every constructor error (``!!float abc``, month 13,
30 February, a 5,000-digit integer) into a :class:`YamlInputError`.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from compensation.registry import short

#: a scenario needs at most ~8 levels (compensation.controller.lines, jitter harmonics)
MAX_DEPTH = 32
#: values in the document once every alias is expanded (a scenario holds a few hundred)
MAX_VALUES = 100_000
#: largest scenario file, bytes (a scenario is a few KB)
MAX_BYTES = 1_000_000

_CORE = "tag:yaml.org,2002:"
ALLOWED_TAGS = frozenset(_CORE + t for t in ("str", "int", "float", "bool", "null", "timestamp",
                                               "seq", "map", "merge")) | {"!"}


class YamlInputError(ValueError):
    """A scenario file that is not acceptable YAML; ``str()`` is one line."""

    def __init__(self, problem: str, mark=None, what: str = ""):
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        if what:
            super().__init__(f"{what} at {where}: {problem}" if where else f"{what}: {problem}")
        else:
            super().__init__(f"{where}: {problem}" if where else problem)


class StrictLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader with the checks of the module docstring."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    # ---------------------------------------------------------------- composing (nodes)
    def compose_node(self, parent, index):
        event = self.peek_event()
        tag = getattr(event, "tag", None)
        if tag is not None and tag not in ALLOWED_TAGS:
            tag = tag.replace(_CORE, "!!")
            raise YamlInputError(f"tag {short(tag, 60)} is not allowed: write plain values "
                                 "(numbers, strings, lists, mappings)", event.start_mark)
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise YamlInputError(f"nesting deeper than {MAX_DEPTH} levels; a scenario needs "
                                     "a few", event.start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def get_single_node(self):
        node = super().get_single_node()
        if node is not None:
            _check_expansion(node)
        return node

    # ------------------------------------------------------------- constructing (values)
    def construct_object(self, node, deep=False):
        try:
            return super().construct_object(node, deep=deep)
        except (YamlInputError, yaml.YAMLError, RecursionError, MemoryError):
            raise
        except Exception as e:  # a constructor's own error: int(), float(), datetime(), ...
            kind = node.tag.rsplit(":", 1)[-1] if node.tag.startswith(_CORE) else node.tag
            detail = " ".join(str(e).split()) or e.__class__.__name__
            raise YamlInputError(f"cannot read {short(node.value)} as {kind} "
                                 f"({short(detail, 100)})", node.start_mark) from None

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == _CORE + "merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # unhashable: PyYAML says so below
                    continue
                if first is not None:
                    raise YamlInputError(
                        f"duplicate key {short(key, 40)} (first at line {first.line + 1}); "
                        "give each key once", key_node.start_mark)
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _check_expansion(root) -> None:
    """Refuse recursive aliases and documents that expand to more than MAX_VALUES values."""
    sizes: dict[int, int] = {}
    active: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            active.discard(key)
            kids = _children(node)
            sizes[key] = 1 + sum(sizes[id(k)] for k in kids)
            if sizes[key] > MAX_VALUES:
                raise YamlInputError(f"the document expands to more than {MAX_VALUES:,} values "
                                     "(anchors and aliases count each time they are used); a "
                                     "scenario needs a few hundred", node.start_mark)
            continue
        if key in sizes:
            continue
        if key in active:
            raise YamlInputError("recursive alias (a value that contains itself)",
                                 node.start_mark)
        active.add(key)
        stack.append((node, True))
        for k in _children(node):
            if id(k) in active:
                raise YamlInputError("recursive alias (a value that contains itself)",
                                     k.start_mark)
            if id(k) not in sizes:
                stack.append((k, False))


def _children(node) -> list:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def read_text(path: Path) -> str:
    """The text of a scenario file; YamlInputError (one line) if it cannot be one."""
    p = Path(path)
    try:
        if not p.exists():
            raise YamlInputError("file not found")
        if p.is_dir():
            raise YamlInputError("is a folder; give the scenario's YAML file")
        if not p.is_file():
            raise YamlInputError("is not a regular file (a pipe or a device); save the "
                                 "scenario to a file")
        size = p.stat().st_size
        if size > MAX_BYTES:
            raise YamlInputError(f"is {size:,} bytes; a scenario is a few KB (largest "
                                 f"{MAX_BYTES:,})")
        return p.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise YamlInputError(f"is not UTF-8 text (byte {e.start}); save it as UTF-8") from None
    except OSError as e:
        raise YamlInputError(f"cannot read the file ({e.strerror or e.__class__.__name__})"
                             ) from None


def load_yaml(text: str):
    """Parse one YAML document strictly (see the module docstring)."""
    try:
        return yaml.load(text, Loader=StrictLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        if isinstance(e, yaml.reader.ReaderError):
            problem = f"character {e.character!r} is not allowed"
        raise YamlInputError(short(problem, 120), mark, "YAML syntax error") from None
    except RecursionError:
        raise YamlInputError(f"nesting deeper than {MAX_DEPTH} levels") from None


def with_changes(data: dict, changes: dict) -> dict:
    """``data`` (a scenario mapping, changed in place and returned) with each dotted key of
    ``changes`` set to its value, creating the sections on the way
    (``{"camera.tracker.rows": 128}``)."""
    for dotted, value in changes.items():
        node = data
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return data
