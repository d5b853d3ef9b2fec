"""Command modules; importing this package fills the command table."""

from . import awareness, dem, hardware, motion, navigation, record, sim, system, workflows  # noqa: F401
