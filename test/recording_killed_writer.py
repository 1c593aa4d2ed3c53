"""Helper for test_recording: write a bag forever, report durable progress, wait to be killed.

Prints ``durable <n>`` each time the writer has fsync'ed more messages. Message i on /counter is
std_msgs/String with data str(i); on /force a force block with t0 = i ms and forces i + k/1000.
"""
import sys
import time

from std_msgs.msg import String

from mantis_rig.recording import BagWriter
from mantis_rig.recording.force_block import force_block_to_msg

T0_NS = 1_700_000_000_000_000_000
MAX_MESSAGES = 200_000


def main(bag_path):
    writer = BagWriter(bag_path, chunk_size_bytes=4096, compression='zstd')
    writer.add_metadata('trial_conditions', {'pull_speed_mm_s': '1.0', 'medium': 'air'})
    reported = 0
    for i in range(MAX_MESSAGES):
        writer.write('/counter', String(data=str(i)), T0_NS + i * 1_000_000)
        forces = [i + k / 1000 for k in range(50)]
        writer.write('/force', force_block_to_msg((T0_NS + i * 1_000_000) / 1e9, 20e-6, forces),
                     T0_NS + i * 1_000_000 + 1)
        durable = writer.durable_message_count
        if durable > reported:
            reported = durable
            print(f'durable {durable}', flush=True)
    print('done', flush=True)
    while True:  # never closes: the test kills us
        time.sleep(1.0)


if __name__ == '__main__':
    main(sys.argv[1])
