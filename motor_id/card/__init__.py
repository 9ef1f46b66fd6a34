"""The serial card: protocol, transport, link, limits and sessions, the simulated card."""
