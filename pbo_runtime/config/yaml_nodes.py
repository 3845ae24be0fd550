"""Safe YAML loading into plain values that remember where every node was written.

The checker reports each mistake at `file:line:col`, so every mapping, key, sequence and
scalar keeps its `Location` (1-based). Mappings load as `YMap` (a dict) and sequences as
`YList` (a list); scalars are plain Python values whose location their container keeps.
Only the safe YAML constructors run (`yaml.SafeLoader`); anything else is a ConfigError.
"""

from __future__ import annotations

import functools
import gc
import operator
import os
from collections.abc import Iterable
from typing import Any

import yaml

from pbo_runtime.config.limits import MAX_FILE_BYTES, show_bytes
from pbo_runtime.config.model import Location
from pbo_runtime.errors import ConfigError

# Aliases can expand a small file into a huge tree ("billion laughs"); a subsystem never needs this many.
MAX_NODES = 200_000

# libyaml's parser (the same safe constructors) is ~10x faster than the pure-Python one; both
# give every node its line and column.
_CSafeLoader = getattr(yaml, "CSafeLoader", None)

if _CSafeLoader is not None:

    class _FastLoader(_CSafeLoader):  # type: ignore[misc, valid-type]
        """libyaml's parser with the implicit-tag resolution memoised: values repeat a lot.

        The composer calls `resolve`, `descend_resolver` and `ascend_resolver` for every node,
        hundreds of thousands of times in a large file, so none of them runs Python code per node:
        `resolve` is wrapped in functools.lru_cache, whose wrapper is C code (a value seen before
        costs no Python call). The other two only track the path for path resolvers, which
        SafeLoader has none of, and the composer ignores what they return; without path
        resolvers they are replaced by C functions that take the same arguments and do nothing
        that matters: `operator.is_(node, index)` and `tuple()`.
        """

        def __init__(self, stream):  # type: ignore[no-untyped-def]
            super().__init__(stream)
            self.resolve = functools.lru_cache(maxsize=None)(super().resolve)
            if not self.yaml_path_resolvers:
                self.descend_resolver = operator.is_
                self.ascend_resolver = tuple

        def dispose(self) -> None:
            # the memo holds the bound method, which holds the loader: drop it so that no cycle
            # keeps the loader (and what it constructed) alive until the next garbage collection
            self.__dict__.pop("resolve", None)
            super().dispose()
else:
    _FastLoader = None  # type: ignore[misc, assignment]  # no libyaml: the pure-Python loader

_MAP_TAG = "tag:yaml.org,2002:map"
_SEQ_TAG = "tag:yaml.org,2002:seq"
_STR_TAG = "tag:yaml.org,2002:str"
_MERGE_TAG = "tag:yaml.org,2002:merge"
_ScalarNode, _SequenceNode, _MappingNode = yaml.ScalarNode, yaml.SequenceNode, yaml.MappingNode
_NOT_BUILT = object()  # a scalar not constructed yet (None is a value)


Where = Any  # a Location, or a YAML mark turned into one only when asked (errors are rare)


# Location(file, line, column) without the NamedTuple's Python-level __new__ (the same tuple):
# the checker asks where nearly every value is, hundreds of thousands of times in a large file.
_new_location = tuple.__new__


def _located(file: str, where: Where) -> Location:
    if isinstance(where, Location):
        return where
    return _new_location(Location, (file, where.line + 1, where.column + 1))


class YMap(dict):  # type: ignore[type-arg]
    """A YAML mapping: a dict that knows where it, each key and each value were written."""

    __slots__ = ("_file", "_key_locs", "_value_locs", "_where")  # no per-instance __dict__: a file has tens of thousands

    def __init__(self, loc: Where, file: str | None = None) -> None:
        super().__init__()
        self._where: Where = loc
        self._file = file if file is not None else loc.file
        self._key_locs: dict[Any, Where] = {}
        self._value_locs: dict[Any, Where] = {}

    @property
    def loc(self) -> Location:
        return _located(self._file, self._where)

    def put(self, key: Any, value: Any, key_loc: Where, value_loc: Where) -> None:
        self[key] = value
        self._key_locs[key] = key_loc
        self._value_locs[key] = value_loc

    def shallow_copy(self) -> YMap:
        """A new mapping of the same keys and values (not copies of them), each still where it was written."""
        copy = YMap(self.loc)
        for key, value in self.items():
            copy.put(key, value, self.key_loc(key), self.value_loc(key))
        return copy

    def key_loc(self, key: Any) -> Location:
        where: Where = self._key_locs.get(key, self._where)
        if isinstance(where, Location):
            return where
        return _new_location(Location, (self._file, where.line + 1, where.column + 1))  # _located, inlined: a hot path

    def value_loc(self, key: Any) -> Location:
        where: Where = self._value_locs.get(key, self._where)
        if isinstance(where, Location):
            return where
        return _new_location(Location, (self._file, where.line + 1, where.column + 1))  # _located, inlined: a hot path


class YList(list):  # type: ignore[type-arg]
    """A YAML sequence: a list that knows where it and each item were written."""

    __slots__ = ("_file", "_item_locs", "_where")

    def __init__(self, loc: Where, file: str | None = None) -> None:
        super().__init__()
        self._where = loc
        self._file = file if file is not None else loc.file
        self._item_locs: list[Where] = []

    @property
    def loc(self) -> Location:
        return _located(self._file, self._where)

    def add(self, value: Any, loc: Where) -> None:
        self.append(value)
        self._item_locs.append(loc)

    def item_loc(self, index: int) -> Location:
        if 0 <= index < len(self._item_locs):
            return _located(self._file, self._item_locs[index])
        return self.loc


def location_of(value: Any, default: Location) -> Location:
    """Where a value was written: its own location if it is a container, else `default`."""
    return value.loc if isinstance(value, (YMap, YList)) else default


def plain(value: Any) -> Any:
    """The same value as ordinary dicts and lists (for specs handed to the runtime)."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


def load_file(path: str | os.PathLike[str], display: str | None = None) -> Any:
    """Load one YAML file; `display` is the name messages use (default: the path as given)."""
    name = display if display is not None else os.fspath(path)
    try:
        with open(path, "rb") as stream:
            size = os.fstat(stream.fileno()).st_size
            if size > MAX_FILE_BYTES:  # before parsing: a huge file costs ~120 bytes of memory per byte
                raise ConfigError(
                    f"the file is {show_bytes(size)}; a configuration file may be at most {show_bytes(MAX_FILE_BYTES)}",
                    name,
                    hint="a file this large is a mistake (a generated list gone wrong?); split a real subsystem with include:",
                )
            data = stream.read(MAX_FILE_BYTES + 1)  # a file that grows while read is cut at the limit
    except IsADirectoryError:
        raise ConfigError("is a directory, not a YAML file", name) from None
    except OSError as exc:
        raise ConfigError(f"cannot read file: {exc.strerror or exc}", name) from None
    return load_text(decode_utf8(data, name), name)


def decode_utf8(data: bytes, name: str) -> str:
    """A file's bytes as text, or a ConfigError at the first byte that is not UTF-8."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        before = data[: exc.start].decode("utf-8", "replace")
        line, column = _line_col(before, len(before))
        raise ConfigError(
            f"not UTF-8 text: byte 0x{data[exc.start]:02x} at byte offset {exc.start} cannot be decoded",
            name,
            line,
            column,
            "save the file as UTF-8 (a configuration is UTF-8 text; is this a binary file?)",
        ) from None


def load_text(text: str, file: str = "<string>") -> Any:
    """Load YAML text into YMap/YList/scalars, or raise ConfigError at the offending mark."""
    # Building hundreds of thousands of small objects makes the cyclic GC rescan the growing
    # heap again and again (quadratic in the file's size); nothing here makes cycles.
    enabled = gc.isenabled()
    gc.disable()
    try:
        return _load_text(text, file)
    finally:
        if enabled:
            gc.enable()


def _load_text(text: str, file: str) -> Any:
    if _FastLoader is not None:
        try:
            return _load(text, file, _FastLoader)
        except (yaml.YAMLError, ConfigError, RecursionError, ValueError, TypeError):
            pass  # say what is wrong in the pure-Python parser's words, which the messages assume
    return _load(text, file, yaml.SafeLoader)


def _load(text: str, file: str, loader_class: type) -> Any:
    loader = None
    try:
        try:
            loader = loader_class(text)  # the reader rejects unprintable characters right here
            node = loader.get_single_node()
            if node is None:
                return None
            # aliases may repeat nodes; a legitimate file has fewer values than characters
            return _Builder(loader, file, max(MAX_NODES, len(text)), "&" in text).build(node)
        except yaml.MarkedYAMLError as exc:
            raise _marked_error(exc, file) from None
        except yaml.reader.ReaderError as exc:
            line, column = _line_col(text, exc.position)
            code = exc.character if isinstance(exc.character, int) else ord(str(exc.character)[:1] or "\0")
            raise ConfigError(
                f"invalid character U+{code:04X} in YAML: {exc.reason}",
                file,
                line,
                column,
                "a configuration is printable UTF-8 text; is this a binary file?",
            ) from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"invalid YAML: {exc}", file, 1, 1) from None
        except RecursionError:
            line, column, depth = _deep_nesting(text)
            raise ConfigError(
                f"YAML is nested too deeply to be a configuration: {depth} lists or mappings inside one another here",
                file,
                line,
                column,
                "a configuration nests a few levels (a matrix is a list of lists); is this file generated?",
            ) from None
    finally:
        if loader is not None:
            loader.dispose()


_DEEP = 100  # levels of nesting no configuration comes near: where a too deep file is reported


def _deep_nesting(text: str) -> tuple[int, int, int]:
    """(line, column, depth) where a file's nesting first reaches `_DEEP` levels of flow lists and
    mappings ([[[...), else where its block nesting is deepest (the most indented line)."""
    depth = 0
    quote = ""
    line, column = 1, 0
    deepest = (1, 1, 0)
    previous = "\n"
    in_comment = False
    for char in text:
        column += 1
        if char == "\n":
            line, column, in_comment, previous = line + 1, 0, False, char
            continue
        if in_comment:
            continue
        if quote:
            if char == quote:
                quote = ""
        elif char in "'\"":
            quote = char
        elif char == "#" and previous in " \t\n":
            in_comment = True
        elif char in "[{":
            depth += 1
            if depth > deepest[2]:
                deepest = (line, column, depth)
            if depth >= _DEEP:
                return deepest
        elif char in "]}":
            depth = max(0, depth - 1)
        previous = char
    if deepest[2] >= 2:
        return deepest
    lines = text.split("\n")  # lines as marks count them: \r or \x0c alone ends no line
    indents = [len(s) - len(s.lstrip(" -")) for s in lines]
    number = indents.index(max(indents))
    written = lines[number]
    return number + 1, len(written) - len(written.lstrip()) + 1, written[:indents[number]].count("-") + 1


def _marked_error(exc: yaml.MarkedYAMLError, file: str) -> ConfigError:
    mark = exc.problem_mark or exc.context_mark
    line, column = (mark.line + 1, mark.column + 1) if mark is not None else (1, 1)
    problem = exc.problem or "invalid YAML"
    hint = ""
    if exc.context:
        hint = exc.context
        if exc.context_mark is not None and exc.context_mark is not mark:
            hint += f" (line {exc.context_mark.line + 1}, column {exc.context_mark.column + 1})"
    if "'\\t'" in problem or "tab" in problem:
        hint = (hint + "; " if hint else "") + "YAML indents with spaces, not tabs"
    return ConfigError(f"invalid YAML: {problem}", file, line, column, hint)


def _line_col(text: str, position: int) -> tuple[int, int]:
    before = text[:position]
    line = before.count("\n") + 1
    column = position - (before.rfind("\n") + 1) + 1
    return line, column


class _Builder:
    """Turns a composed node graph into YMap/YList/scalars, keeping each node's location.

    It runs once per node of the file (hundreds of thousands in a large subsystem), so scalars,
    most of the nodes, take a short path: counted, then looked up among those already built.
    """

    def __init__(self, loader: yaml.SafeLoader, file: str, max_nodes: int = 0, anchors: bool = True) -> None:
        self._loader = loader
        self._anchors = anchors  # False: the text has no '&', so no alias can make a node contain itself
        self._file = file
        self._max_nodes = max_nodes or MAX_NODES
        self._scalars: dict[str, dict[str, Any]] = {}  # tag -> written text -> value
        # Most scalars are text, which the safe constructor returns as written (unless replaced)
        self._plain_strings = loader.yaml_constructors.get(_STR_TAG) is yaml.constructor.SafeConstructor.construct_yaml_str
        self._count = 0
        self._active: set[int] = set()

    def loc(self, node: yaml.Node) -> Location:
        mark = node.start_mark
        return Location(self._file, mark.line + 1, mark.column + 1)

    def build(self, node: yaml.Node, section: Any = "") -> Any:
        """The value of `node`; `section` is the key it sits under, which a duplicate key's message names."""
        if isinstance(node, _ScalarNode):
            return self._scalar(node)
        self._count_node(node)
        if not self._anchors:
            if isinstance(node, _MappingNode):
                return self._mapping(node, section)
            if isinstance(node, _SequenceNode):
                return self._sequence(node, section)
        elif id(node) in self._active:
            raise ConfigError(
                "an alias refers to a node that contains it (a recursive structure)", self._file, *self._line_col(node)
            )
        self._active.add(id(node))
        try:
            if isinstance(node, _SequenceNode):
                return self._sequence(node, section)
            if isinstance(node, _MappingNode):
                return self._mapping(node, section)
        finally:
            self._active.discard(id(node))
        raise ConfigError(f"unexpected YAML node {type(node).__name__}", self._file, *self._line_col(node))

    def _count_node(self, node: yaml.Node) -> None:
        """Every node built counts, aliased ones each time: an alias bomb stops at the limit."""
        self._count += 1
        if self._count > self._max_nodes:
            raise self._too_many(node)

    def _too_many(self, node: yaml.Node) -> ConfigError:
        return ConfigError(
            f"YAML expands to more than {self._max_nodes} values (through aliases?)",
            self._file,
            *self._line_col(node),
            "a configuration this large is a mistake; check anchors (&) and aliases (*)",
        )

    def _scalar(self, node: yaml.ScalarNode) -> Any:
        self._count += 1  # as _count_node does, without a call per scalar
        if self._count > self._max_nodes:
            raise self._too_many(node)
        return self._scalar_value(node)

    def _add_scalars(self, count: int, node: yaml.Node) -> None:
        """Count the scalars of one container at once (`_count_node` for each of them)."""
        self._count += count
        if self._count > self._max_nodes:
            raise self._too_many(node)

    def _scalar_value(self, node: yaml.ScalarNode) -> Any:
        """A scalar's value (not counted: the caller counts it)."""
        built = self._scalars.get(node.tag)
        if built is None:
            built = self._scalars[node.tag] = {}
        value = built.get(node.value, _NOT_BUILT)
        if value is not _NOT_BUILT:  # scalars are immutable: construct each distinct one once
            return value
        if node.tag == _STR_TAG and self._plain_strings:
            value = built[node.value] = node.value  # what construct_yaml_str returns, without its calls
            return value
        try:
            value = built[node.value] = self._loader.construct_object(node, deep=True)
            return value
        except (ValueError, TypeError, OverflowError) as exc:  # e.g. a date like 2024-02-30
            raise ConfigError(f"cannot read value {node.value!r}: {exc}", self._file, *self._line_col(node)) from None

    def _line_col(self, node: yaml.Node) -> tuple[int, int]:
        loc = self.loc(node)
        return loc.line, loc.column

    def _check_tag(self, node: yaml.Node, expected: str) -> None:
        if node.tag != expected:
            raise ConfigError(
                f"YAML tag '{node.tag}' is not supported here",
                self._file,
                *self._line_col(node),
                "remove the tag; a configuration uses plain mappings, lists and scalars",
            )

    def _sequence(self, node: yaml.SequenceNode, section: Any) -> YList:
        if node.tag != _SEQ_TAG:
            self._check_tag(node, _SEQ_TAG)
        result = YList(node.start_mark, self._file)
        item_locs = result._item_locs  # what YList.add fills, without a call per item
        plain_strings, scalars = self._plain_strings, 0
        for item in node.value:
            # a scalar (most items) takes the inlined short path of `_scalar`; its count is added below
            if item.__class__ is _ScalarNode:
                scalars += 1
                value = item.value if plain_strings and item.tag == _STR_TAG else self._scalar_value(item)
            else:
                value = self.build(item, section)
            result.append(value)
            item_locs.append(item.start_mark)
        self._add_scalars(scalars, node)
        return result

    def _mapping(self, node: yaml.MappingNode, section: Any) -> YMap:
        if node.tag != _MAP_TAG:
            self._check_tag(node, _MAP_TAG)
        result = YMap(node.start_mark, self._file)
        key_locs, value_locs = result._key_locs, result._value_locs  # what YMap.put fills, without a call per key
        merges: list[yaml.Node] = []
        # Keys and scalar values, most of a file's nodes, take the inlined short path of `_scalar`
        # (text is its own value), and are counted once per mapping: this loop runs for every
        # entry of the file.
        plain_strings, scalars = self._plain_strings, 0
        for key_node, value_node in node.value:
            if plain_strings and key_node.__class__ is _ScalarNode and key_node.tag == _STR_TAG:
                key = key_node.value
            else:
                if key_node.tag == _MERGE_TAG:
                    merges.append(value_node)
                    continue
                if not isinstance(key_node, _ScalarNode):
                    raise ConfigError(
                        "a key must be a plain name, got a " + ("list" if isinstance(key_node, _SequenceNode) else "mapping"),
                        self._file,
                        *self._line_col(key_node),
                    )
                key = self._scalar_value(key_node)
                try:
                    hash(key)
                except TypeError:
                    raise ConfigError(
                        f"a key must be a plain name, got: {key!r}", self._file, *self._line_col(key_node)
                    ) from None
            scalars += 1
            if key in result:
                raise self._duplicate_key(result, key, key_node, section)
            if value_node.__class__ is _ScalarNode:
                scalars += 1
                value = value_node.value if plain_strings and value_node.tag == _STR_TAG else self._scalar_value(value_node)
            else:
                value = self.build(value_node, key)
            result[key] = value
            key_locs[key] = key_node.start_mark
            value_locs[key] = value_node.start_mark
        self._add_scalars(scalars, node)
        for merge in merges:
            # `<<: *defaults` - explicit keys win over merged ones, as YAML 1.1 says.
            sources: Iterable[yaml.Node] = merge.value if isinstance(merge, _SequenceNode) else [merge]
            for source_node in sources:
                source = self.build(source_node, section)
                if not isinstance(source, YMap):
                    raise ConfigError(
                        "a merge key (<<) takes a mapping or a list of mappings", self._file, *self._line_col(source_node)
                    )
                for key, value in source.items():
                    if key not in result:
                        result.put(key, value, source.key_loc(key), source.value_loc(key))
        return result

    def _duplicate_key(self, result: YMap, key: Any, key_node: yaml.Node, section: Any) -> ConfigError:
        first = result.key_loc(key)
        named = {"tasks": "task", "variables": "variable", "configurations": "configuration", "jobs": "job",
                 "applications": "application", "devices": "device", "dims": "dim"}.get(str(section))
        return ConfigError(
            f"duplicate key '{key}'" + (f" in {section}" if section else "")
            + f" (first at line {first.line}, column {first.column})",
            self._file,
            *self._line_col(key_node),
            f"{named} names are unique; rename one of the two" if named
            else "a mapping names each key once; remove or rename one of them",
        )
