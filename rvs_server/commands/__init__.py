"""Command modules; importing this package fills the command table."""

from . import hardware, sim, system  # noqa: F401
