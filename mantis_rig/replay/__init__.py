"""Replay of trial bags: republish recorded messages with their original relative timing."""
from .player import BagPlayer, PlaybackReport, ReplayError
from .qos import replay_qos
from .schedule import PlaybackClock, TimingStats

__all__ = ['BagPlayer', 'PlaybackClock', 'PlaybackReport', 'ReplayError', 'TimingStats',
           'replay_qos']
