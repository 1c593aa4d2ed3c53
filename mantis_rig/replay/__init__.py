"""Replay of trial bags: republish recorded messages with their original relative timing."""
from mantis_rig.replay.replay_qos import replay_qos

from .player import BagPlayer, PlaybackReport, ReplayError
from .schedule import PlaybackClock, TimingStats

__all__ = ['BagPlayer', 'PlaybackClock', 'PlaybackReport', 'ReplayError', 'TimingStats',
           'replay_qos']
