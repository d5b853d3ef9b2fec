"""The client side of the wire protocol, installed with the server so that an operator's
machine with ``pip install rvs-server`` has ``rvs-client`` and ``rvs-replay`` too: ``session``
(one connection, request/reply correlation, a server in a child process for tests), ``console``
(rvs-client) and ``replay`` (rvs-replay)."""
