"""The engine's value types: short names a step declares its inputs and outputs with, and which
given type may go where another is wanted."""

from __future__ import annotations

import ast
from typing import Any

# Types are short names: float, int, str, bool, floats (a list of numbers), dict, list, array,
# path, Layers, View, ... ; ``list[T]`` a list of T; a trailing ``?`` allows None; ``any`` anything.


def base_type(t: str) -> tuple[str, bool]:
    return (t[:-1], True) if t.endswith("?") else (t, False)


def compatible(given: str, wanted: str) -> bool:
    """Can a value of type ``given`` go where ``wanted`` is declared?"""
    g, g_opt = base_type(given)
    w, w_opt = base_type(wanted)
    if g == "any" or w == "any":
        return True
    if g == "none":
        return w_opt
    if g_opt and not w_opt:
        return False
    if g == w:
        return True
    if (g, w) in (("int", "float"), ("floats", "list"), ("str", "path"), ("path", "str")):
        return True
    if g.startswith("list[") and w == "list":
        return True
    if g.startswith("list[") and w.startswith("list["):
        return compatible(g[5:-1], w[5:-1])
    if g == "floats" and w.startswith("list["):
        return compatible("float", w[5:-1])
    if g == "list" and w.startswith("list["):
        return True  # a literal list: its items are checked when the step runs
    return False


def literal_type(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "str"
    if isinstance(value, list | tuple):
        if value and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            return "floats"
        return "list"
    if isinstance(value, dict):
        return "dict"
    return "any"


PARAM_KIND = {"float": "float", "int": "int", "str": "str", "bool": "bool", "floats": "floats", "dict": "dict"}


# A step's input types are read from its function's annotations, as written (scripts and steps
# name types that need not be importable here): float, int, str, bool as themselves; Path, and
# str | Path, as path; np.ndarray as array; list[float], Sequence[float] and tuples of floats as
# floats; a list of one of the engine's named types as list[T], any other list as list; dict and
# Mapping as dict; a class by its name (Layers, View, NavMaps ...); Any, and a union of several
# types, as any; "| None" adds "?".
_ANNOTATED = {"float": "float", "int": "int", "str": "str", "bool": "bool", "Path": "path", "Any": "any",
              "dict": "dict", "Mapping": "dict", "list": "list", "ndarray": "array"}
_PLAIN = {"float", "int", "str", "bool", "path", "any", "list", "dict", "floats", "array"}


def annotation_type(annotation: str) -> str:
    """The engine type of a step argument annotated ``annotation`` (the text, unevaluated)."""
    return _union(ast.parse(annotation, mode="eval").body)


def _name(node: ast.expr) -> str | None:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    if isinstance(node, ast.Constant) and node.value is None:
        return "None"
    return None


def _members(node: ast.expr) -> list[ast.expr]:
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
        return _members(node.left) + _members(node.right)
    return [node]


def _union(node: ast.expr) -> str:
    members = _members(node)
    optional = any(_name(m) == "None" for m in members)
    rest = [m for m in members if _name(m) != "None"]
    if {_name(m) for m in rest} == {"str", "Path"}:
        base = "path"
    else:
        bases = {_one(m) for m in rest}
        base = bases.pop() if len(bases) == 1 else "any"
    return base if base == "any" or not optional else base + "?"


def _one(node: ast.expr) -> str:
    if isinstance(node, ast.Subscript):
        outer = _name(node.value)
        args = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
        if outer in ("list", "Sequence"):
            inner = _union(args[0])
            if inner == "float":
                return "floats"
            return "list" if base_type(inner)[0] in _PLAIN else f"list[{inner}]"
        if outer == "tuple":
            return "floats" if all(_name(a) == "float" for a in args) else "any"
        return "dict" if outer in ("dict", "Mapping") else "any"
    name = _name(node)
    return "any" if name is None else _ANNOTATED.get(name, name)
