"""The strict YAML loader of the package (:class:`StrictLoader`, :class:`FiniteLoader`,
:func:`strict_load`); :mod:`lpv_sysid.io.files.yaml_reader` reads and writes the files with it.

The loader is the libyaml parser (``yaml.CParser``, about 5x faster than the pure-Python
one) under a Python composer and ``SafeConstructor`` that add what PyYAML does not check:

* **duplicate mapping keys** are an error (PyYAML silently keeps the last one);
* **nesting** deeper than :data:`MAX_DEPTH` collections is refused while composing (the
  libyaml composer recurses in C and crashes the interpreter on ~10^5 levels; the
  pure-Python one raises RecursionError);
* **aliases** may add at most :data:`MAX_ALIAS_NODES` nodes to the document ("billion
  laughs": ``*lol9`` expands to 10^9 nodes in anything that walks the data), and an alias
  inside its own anchor (a cyclic document) is refused;
* **integers** must fit 64 bits (``10**400`` does not fit any field and overflows
  ``float()``), and a float literal that overflows a double (``1.0e+400``) is refused;
* in **configuration files** (the default ``finite=True`` of
  :func:`~lpv_sysid.io.files.yaml_reader.read_yaml`; the package's own outputs are read with
  ``finite=False``) every float must be finite (``.nan``, ``.inf`` refused) and at most
  :data:`MAX_MAGNITUDE` in magnitude; the message names the key path
  (``groups[0].peak: .inf is not a finite number``). The versioned model/gains files check
  the same per field (:mod:`lpv_sysid.io.formats`).
"""

from __future__ import annotations

import math
from typing import Any

import yaml
from yaml.composer import Composer, ComposerError
from yaml.constructor import ConstructorError, SafeConstructor
from yaml.events import AliasEvent, MappingStartEvent, SequenceStartEvent
from yaml.nodes import MappingNode, ScalarNode, SequenceNode
from yaml.resolver import Resolver

#: Deepest nesting of collections accepted (the package's files nest <= 8 levels).
MAX_DEPTH = 100
#: Most nodes aliases may add to a document when expanded.
MAX_ALIAS_NODES = 1_000_000
#: Integers must satisfy ``|x| <= INT_LIMIT`` (int64).
INT_LIMIT = 2**63 - 1
#: Largest magnitude of a float in a configuration file, and of a matrix entry in a models or
#: gains file: no SI quantity of the package comes near it, and products of up to ~20 such
#: factors (Gramians, Hamiltonians, ``B R R^T B^T``, squared norms) stay finite in double
#: precision, so a value like ``R: 1.0e+308`` is refused at the file instead of overflowing later.
MAX_MAGNITUDE = 1e15

if getattr(yaml, "__with_libyaml__", False):
    # the libyaml binding (types-PyYAML does not list it among yaml.cyaml's exports: see the
    # attr-defined exemption of this module in setup.cfg)
    from yaml.cyaml import CParser as _Parser
else:  # pragma: no cover - PyYAML without libyaml: same checks, slower parser
    from yaml.parser import Parser
    from yaml.reader import Reader
    from yaml.scanner import Scanner

    class _Parser(Reader, Scanner, Parser):  # type: ignore[no-redef]
        def __init__(self, stream):
            Reader.__init__(self, stream)
            Scanner.__init__(self)
            Parser.__init__(self)


class StrictYAMLError(yaml.MarkedYAMLError):
    """A document PyYAML would accept but this loader refuses (``problem`` + ``problem_mark``)."""

    def __init__(self, problem: str, mark=None):
        super().__init__(None, None, problem, mark)


class NonFiniteError(StrictYAMLError):
    """A float that is not finite, or beyond :data:`MAX_MAGNITUDE`, in a configuration file."""


class _StrictComposer(Composer):
    """Composer with a nesting limit and alias-expansion accounting (``node._n`` = number of
    nodes of the subtree with aliases expanded; absent while the node is being composed)."""

    def compose_document(self):
        self._depth = 0
        self._alias_nodes = 0
        return super().compose_document()

    def compose_node(self, parent, index):
        if self.check_event(AliasEvent):
            event = self.get_event()
            node = self.anchors.get(event.anchor)
            if node is None:
                raise ComposerError(
                    None, None, f"found undefined alias {event.anchor!r}", event.start_mark
                )
            n = getattr(node, "_n", None)
            if n is None:
                raise StrictYAMLError(
                    f"alias *{event.anchor} refers to its own enclosing anchor (cyclic document)",
                    event.start_mark,
                )
            self._alias_nodes += n
            if self._alias_nodes > MAX_ALIAS_NODES:
                raise StrictYAMLError(
                    f"aliases expand the document by more than {MAX_ALIAS_NODES} nodes "
                    f"(alias *{event.anchor}; an alias bomb?)",
                    event.start_mark,
                )
            return node
        if self.check_event(SequenceStartEvent, MappingStartEvent):
            self._depth += 1
            if self._depth > MAX_DEPTH:
                raise StrictYAMLError(
                    f"nesting deeper than {MAX_DEPTH} levels", self.peek_event().start_mark
                )
            node = super().compose_node(parent, index)
            self._depth -= 1
            if isinstance(node, MappingNode):
                node._n = 1 + sum(k._n + v._n for k, v in node.value)
            else:
                node._n = 1 + sum(c._n for c in node.value)
            return node
        node = super().compose_node(parent, index)  # scalar
        node._n = 1
        return node


class _StrictConstructor(SafeConstructor):
    """SafeConstructor refusing duplicate keys, integers beyond int64 and overflowing floats."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, MappingNode):
            seen: dict[Any, int] = {}  # key -> line of its first occurrence
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.get(key)
                except TypeError:  # unhashable key: SafeConstructor says so below
                    continue
                if first is not None:
                    raise ConstructorError(
                        None,
                        None,
                        f"duplicate key {key!r} (first at line {first + 1})",
                        key_node.start_mark,
                    )
                seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)

    def construct_yaml_int(self, node):
        text = str(node.value)
        if len(text.replace("_", "")) > 80:
            raise ConstructorError(
                None,
                None,
                f"integer {text[:20]}... ({len(text)} characters) is out of "
                f"range (|x| <= 2**63 - 1)",
                node.start_mark,
            )
        value = super().construct_yaml_int(node)
        if abs(value) > INT_LIMIT:
            raise ConstructorError(
                None, None, f"integer {text} is out of range (|x| <= 2**63 - 1)", node.start_mark
            )
        return value

    def construct_yaml_float(self, node):
        value = super().construct_yaml_float(node)
        if math.isinf(value) and str(node.value).lstrip("+-").lower() != ".inf":
            raise ConstructorError(
                None,
                None,
                f"float {node.value} overflows a double (|x| > 1.8e308)",
                node.start_mark,
            )
        return value


# (the stubs type add_constructor for the stock constructor classes only)
_StrictConstructor.add_constructor(  # type: ignore[type-var]
    "tag:yaml.org,2002:int", _StrictConstructor.construct_yaml_int
)
_StrictConstructor.add_constructor(  # type: ignore[type-var]
    "tag:yaml.org,2002:float", _StrictConstructor.construct_yaml_float
)


class StrictLoader(_StrictComposer, _Parser, _StrictConstructor, Resolver):
    """libyaml parser + the strict composer/constructor above (a ``yaml.load`` Loader)."""

    #: refuse non-finite floats and floats beyond MAX_MAGNITUDE (configuration files)
    finite = False

    def __init__(self, stream):
        _Parser.__init__(self, stream)
        _StrictComposer.__init__(self)
        _StrictConstructor.__init__(self)
        Resolver.__init__(self)

    def get_single_data(self):
        node = self.get_single_node()
        if node is None:
            return None
        if self.finite:
            self._check_floats(node)
        return self.construct_document(node)

    def _check_floats(self, root) -> None:
        """Walk the node tree (each node once; aliases are shared nodes) for float scalars
        that are not finite or too large; the error names the key path."""
        seen: set = set()
        stack = [(root, "")]
        while stack:
            node, path = stack.pop()
            if id(node) in seen:
                continue
            seen.add(id(node))
            if isinstance(node, MappingNode):
                for k, v in reversed(node.value):
                    key = k.value if isinstance(k, ScalarNode) else "?"
                    stack.append((v, f"{path}.{key}" if path else str(key)))
            elif isinstance(node, SequenceNode):
                for i in range(len(node.value) - 1, -1, -1):
                    stack.append((node.value[i], f"{path}[{i}]"))
            elif node.tag == "tag:yaml.org,2002:float":
                x = self.construct_yaml_float(node)
                where = f"{path}: " if path else ""
                if not math.isfinite(x):
                    raise NonFiniteError(
                        f"{where}{node.value} is not a finite number (a finite number "
                        "is required)",
                        node.start_mark,
                    )
                if abs(x) > MAX_MAGNITUDE:
                    raise NonFiniteError(
                        f"{where}{node.value} is too large (|x| <= {MAX_MAGNITUDE:g})",
                        node.start_mark,
                    )


class FiniteLoader(StrictLoader):
    """:class:`StrictLoader` that also refuses non-finite and too large floats."""

    finite = True


def strict_load(text: str, finite: bool = False) -> Any:
    """One YAML document of ``text`` with :class:`StrictLoader` (``finite``:
    :class:`FiniteLoader`); raises ``yaml.YAMLError``."""
    # SafeConstructor-based Loader; the stubs list only PyYAML's own Loader classes
    loader = FiniteLoader if finite else StrictLoader
    return yaml.load(text, Loader=loader)  # type: ignore[arg-type]


def describe_yaml_error(exc: yaml.YAMLError) -> str:
    """First line of a parser error; the refusals of this loader with their line and column."""
    if (
        isinstance(exc, (StrictYAMLError, ConstructorError))
        and exc.context is None
        and exc.problem
    ):
        mark = exc.problem_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        return f"{where}{exc.problem}"
    return (str(exc).splitlines() or [type(exc).__name__])[0]
