"""The operator web console (seed 000 sect. 4.4.4's click-a-destination GUI), served by the
server itself on ``server.web_port``."""
