"""The argument parser every toolbox program uses: option values may be negative numbers and lists.

argparse takes any word that starts with '-' and is not a plain negative number for an option, so
``--bounds -2,-3,4,5`` or ``--start -1.5,2`` fail with "expected one argument". A word that starts
with '-' and a digit (or '-.' and a digit) and holds nothing but number and list characters is a
value here, as Python 3.13's argparse does for any '-digit' word; no program here has an option
that looks like a negative number, which is the one case where argparse would still read it as one.
"""

from __future__ import annotations

import argparse
import re
from typing import Any

NEGATIVE_VALUE = re.compile(r"^-\.?\d[\d.eE+,-]*$")


class ToolParser(argparse.ArgumentParser):
    """argparse.ArgumentParser for programs whose option values are coordinates and extents."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # argparse's own hook for "is this '-...' word a value?" (also consulted by subparsers,
        # which are built with this class)
        self._negative_number_matcher = NEGATIVE_VALUE
