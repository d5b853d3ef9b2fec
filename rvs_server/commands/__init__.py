"""Command modules; importing this package fills the command table."""

from . import dem, hardware, navigation, sim, system  # noqa: F401
