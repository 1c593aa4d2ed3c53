"""Trial logs: rosbag2 bag directories with MCAP storage (write, read, recover)."""
from .reader import BagError, BagMessage, BagReader, TopicInfo, TruncatedBagWarning, read_bag
from .recover import RecoveryReport, main_recover, recover_bag
from .writer import TRIAL_CONDITIONS, TRIAL_OUTCOME, BagClosedError, BagWriteError, BagWriter

__all__ = [
    'BagClosedError', 'BagError', 'BagWriteError', 'BagMessage', 'BagReader', 'BagWriter',
    'RecoveryReport',
    'TopicInfo', 'TRIAL_CONDITIONS', 'TRIAL_OUTCOME', 'TruncatedBagWarning', 'main_recover',
    'read_bag', 'recover_bag',
]
