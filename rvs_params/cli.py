"""The command line every installed program shares (``rvs-server``, ``rvs-client``, the device
consoles, the toolbox): how its options are parsed and how a bad one is said.

A bad option, value or input is one ``tool: message`` line on stderr and exit status 2 (the
usage is what ``--help`` prints, not a block in front of the error), and the message names the
option as it is typed on that command line (``--cell``), not as the wire spells it (``-cell``).
It lives here, beside the declarations the options are parsed by, because the server, the
drivers and the toolbox all use it and may not import each other.

Option values may be negative numbers and lists: argparse takes any word that starts with '-'
and is not a plain negative number for an option, so ``--bounds -2,-3,4,5`` or ``--start -1.5,2``
would fail with "expected one argument". A word that starts with '-' and a digit (or '-.' and a
digit) and holds nothing but number and list characters is a value here, as Python 3.13's
argparse does for any '-digit' word, and so are ``-inf``, ``-Infinity`` and ``-nan`` (as on the
wire: the option's own check then says it wants a finite number), also leading a list; no
program here has an option that looks like a negative number, which is the one case where
argparse would still read it as one.
"""

from __future__ import annotations

import argparse
import re
import sys
from typing import Any, NoReturn

NEGATIVE_VALUE = re.compile(r"^-(\.?\d[\d.eE+,-]*|(inf|infinity|nan)(,[\w.+-]*)*)$", re.IGNORECASE)


class ToolParser(argparse.ArgumentParser):
    """argparse.ArgumentParser with one-line errors and values that may be negative numbers."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # argparse's own hook for "is this '-...' word a value?" (also consulted by subparsers,
        # which are built with this class)
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {one_line(message)}; {self.prog} --help lists the options\n")


def one_line(text: str) -> str:
    """``text`` on one line (a message quoting a wrapped usage, a YAML excerpt)."""
    return " ".join(str(text).split())


def fail(prog: str, message: object, status: int = 2) -> int:
    """Say what is wrong as one ``prog: message`` line on stderr; returns the exit status."""
    print(f"{prog}: {one_line(str(message))}", file=sys.stderr)
    return status
