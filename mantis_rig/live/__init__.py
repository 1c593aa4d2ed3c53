"""The live view: a running trial's (or a replay's) topics relayed to Foxglove over WebSocket."""
from .relay import LiveRelay

__all__ = ['LiveRelay']
