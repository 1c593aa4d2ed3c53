"""Rewrite a crashed or truncated bag into a valid one (new MCAP with summary + metadata.yaml).

Every complete message the reader can get (see :class:`~.reader.BagReader`) is copied, with the
original schemas, channel metadata (offered QoS, type hash) and metadata records, into a new bag
directory (default ``<bag>_recovered``); the damaged bag is left untouched. A
``mantis_recovery`` metadata record says where the data came from and what was lost.
"""
import argparse
from dataclasses import dataclass, field
from pathlib import Path
import sys

from mantis_rig.recording.offered_qos import parse_offered_qos_string

from .bag_metadata import ROSBAG2_RECORD_NAME
from .reader import BagReader
from .writer import BagWriter

RECOVERY_RECORD = 'mantis_recovery'


@dataclass
class RecoveryReport:
    source: Path
    output: Path
    messages_recovered: int
    topic_counts: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)  # what was wrong with the source

    def __str__(self):
        lines = [f'recovered {self.messages_recovered} messages from {self.source} '
                 f'into {self.output}']
        lines += [f'  {topic}: {count}' for topic, count in self.topic_counts.items()]
        lines += [f'  source problem: {problem}' for problem in self.problems] or \
                 ['  source was intact']
        return '\n'.join(lines)


def _default_output(reader):
    return reader.bag_dir.with_name(reader.bag_dir.name + '_recovered')


def recover_bag(path, output=None):
    """Copy every readable message of the bag at ``path`` into a new valid bag at ``output``."""
    reader = BagReader(path, warn=False)
    output = Path(output) if output is not None else _default_output(reader)
    counts = {}
    with BagWriter(output, sync_period_s=0) as writer:
        for topic, info in reader.topics.items():
            writer.add_topic_definition(
                topic, info.type_name,
                parse_offered_qos_string(info.metadata.get('offered_qos_profiles', '')),
                info.schema_text, info.metadata.get('topic_type_hash', ''))
            counts[topic] = 0
        for name, data in reader.metadata_records:
            if name not in (ROSBAG2_RECORD_NAME, RECOVERY_RECORD):
                writer.add_metadata(name, data)
        for channel, _, message in reader.raw_messages():
            writer.write_serialized(channel.topic, message.data, message.log_time,
                                    message.publish_time)
            counts[channel.topic] += 1
        writer.add_metadata(RECOVERY_RECORD, {
            'source': str(reader.path),
            'messages_recovered': str(sum(counts.values())),
            'source_problems': '; '.join(reader.problems) or 'none',
        })
    return RecoveryReport(source=reader.path, output=output,
                          messages_recovered=sum(counts.values()), topic_counts=counts,
                          problems=list(reader.problems))


def main_recover(argv=None):
    """``mantis recover BAG [-o OUTPUT]``; returns a process exit code."""
    parser = argparse.ArgumentParser(
        prog='mantis recover',
        description='Rewrite a crashed/truncated trial bag into a valid rosbag2 MCAP bag.')
    parser.add_argument('bag', help='bag directory (or its .mcap file)')
    parser.add_argument('-o', '--output', help='new bag directory (default: <bag>_recovered)')
    args = parser.parse_args(argv)
    try:
        report = recover_bag(args.bag, args.output)
    except (FileExistsError, OSError) as exc:      # a BagError (bad input) goes up: exit 2
        print(f'mantis recover: {exc}', file=sys.stderr)
        return 1
    print(report)
    if report.messages_recovered == 0:
        print(f'mantis recover: no message could be recovered from {args.bag}', file=sys.stderr)
        return 1
    return 0
