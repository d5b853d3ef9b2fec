"""Numbers as the wire writes them: ASCII decimal (PROTOCOL.md), on every path a value is read by
(options, lists, ``config -set``, YAML-valued keys)."""

from __future__ import annotations

import re
from typing import Any

# Numbers on the wire are ASCII decimal (PROTOCOL.md): Python's float() and int() also take
# "1_0", a full-width "９" or other Unicode digits, and blanks round them, none of which a GNC
# sends on purpose. inf and nan are read as numbers so that the finite check names them.
NUMBER_RE = re.compile(r"[+-]?(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf|infinity|nan)",
                       re.IGNORECASE)
INTEGER_RE = re.compile(r"[+-]?[0-9]+")
NUMBER_FORM = "ASCII decimal like -12, 0.5 or 1e-3"
INTEGER_FORM = "ASCII digits like 12 or -3"


def is_number(text: str) -> bool:
    """Whether ``text`` is a number as the wire writes it (inf and nan included)."""
    return NUMBER_RE.fullmatch(text) is not None


def parse_number(text: str, form: str) -> float:
    """``text`` as a float if it is written in ASCII decimal; ValueError naming ``form`` if not."""
    if not is_number(text):
        raise ValueError(form)
    return float(text)


def parse_integer(text: str) -> int:
    """``text`` as an int if it is ASCII digits; ValueError otherwise."""
    if INTEGER_RE.fullmatch(text) is None:
        raise ValueError(INTEGER_FORM)
    return int(text, 10)


_YAML_WORD = re.compile(r"[^\s\[\]{},:]+")


def load_wire_yaml(text: str) -> Any:
    """A YAML value typed on the wire (a matrix, a list): its numbers must be ASCII decimal too,
    whereas YAML also reads ``1_0``, ``0x10``, ``0o17`` or ``.inf`` as numbers. ValueError
    names the first such word; yaml.YAMLError for text that is no YAML."""
    import yaml

    for word in _YAML_WORD.findall(text):
        if type(yaml.safe_load(word)) in (int, float) and not is_number(word):  # (a bool is no number here)
            raise ValueError(f"'{word[:20]}' is not a number in {NUMBER_FORM}")
    return yaml.safe_load(text)
