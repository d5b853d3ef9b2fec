"""Command modules; importing this package fills the command table."""

from . import system  # noqa: F401
