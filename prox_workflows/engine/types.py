"""The engine's value types: short names a step declares its inputs and outputs with, and which
given type may go where another is wanted."""

from __future__ import annotations

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
