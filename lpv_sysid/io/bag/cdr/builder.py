"""Message objects built from decoded columns (what :func:`~lpv_sysid.io.bag.reader.read_bag`
returns for fixed-layout records): one generated constructor expression per layout, so
that ``n`` messages cost ``n`` class calls and nothing else."""

from __future__ import annotations

from typing import Any, Callable, Mapping

from lpv_sysid.io.bag.cdr.layout import CdrLayout

_BUILDERS: dict[tuple, Callable[[Mapping, int], list]] = {}


def _builder(store: Any, lay: CdrLayout) -> Callable[[Mapping, int], list]:
    """A function ``build(fields, n) -> [msg, ...]`` constructing ``n`` rosbags messages of
    ``lay``'s shape from decoded columns (what ``deserialize_cdr`` returns, field by field:
    Python scalars, read-only numpy arrays, lists of strings)."""
    key = (
        id(store),
        lay.msgtype,
        lay.size,
        lay.struct_bytes.tobytes(),
        lay.struct_index.tobytes(),
    )
    fn = _BUILDERS.get(key)
    if fn is not None:
        return fn
    from rosbags.interfaces import Nodetype

    ns: dict = {}
    scalars: list = []
    arrays: list = []

    def name_of(obj, prefix):
        k = f"{prefix}{len(ns)}"
        ns[k] = obj
        return k

    def msg_expr(msgtype, prefix):
        cls = name_of(store.types[msgtype], "T")
        parts = [field_expr(desc, prefix + fname) for fname, desc in store.fielddefs[msgtype][1]]
        return f"{cls}({', '.join(parts)})"

    def field_expr(desc, path):
        kind, arg = desc
        if kind == Nodetype.NAME:
            return msg_expr(arg, path + ".")
        if kind == Nodetype.BASE:
            if arg[0] == "string":
                return name_of(lay.strings[path], "S")
            scalars.append(path)
            return f"v{len(scalars) - 1}[i]"
        sub = arg[0] if kind == Nodetype.SEQUENCE else arg[0]
        if sub[0] == Nodetype.BASE and sub[1][0] != "string":
            arrays.append(path)
            return f"a{len(arrays) - 1}[i]"
        if sub[0] == Nodetype.BASE:
            return f"list({name_of(lay.strings[path], 'S')})"
        n = lay.counts[path]
        return "[" + ", ".join(msg_expr(sub[1], f"{path}[{j}].") for j in range(n)) + "]"

    expr = msg_expr(lay.msgtype, "")
    args = [f"v{k}" for k in range(len(scalars))] + [f"a{k}" for k in range(len(arrays))]
    src = f"def build({', '.join(args + ['n'])}):\n    return [{expr} for i in range(n)]\n"
    exec(compile(src, f"<lpv_sysid.io.bag builder {lay.msgtype}>", "exec"), ns)  # noqa: S102
    inner = ns["build"]

    def build(fields_: Mapping, n: int) -> list:
        cols = [fields_[p].tolist() for p in scalars]
        arrs = []
        for p in arrays:
            a = fields_[p]
            a.flags.writeable = False  # rosbags' arrays are read-only views too
            arrs.append(a)
        return inner(*cols, *arrs, n)

    _BUILDERS[key] = build
    return build
