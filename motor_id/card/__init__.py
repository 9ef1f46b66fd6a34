"""The simulated serial card: frame protocol and a virtual card on a pseudo-terminal."""
