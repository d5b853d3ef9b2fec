"""RVS server: the GNC's text-command interface to the rover vision system."""

__version__ = "0.1.0"
PROTOCOL_VERSION = 1
