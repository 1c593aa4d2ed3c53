"""Keep DDS on this machine: loopback discovery and a ROS domain of this run's own.

Must run before rclpy.init(). `claim_local_domain()` sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
(unless the caller set a range) and, when ROS_DOMAIN_ID is unset, picks a domain no other
mantis process on this machine holds: each claim is an exclusive lock on a file in the temp
directory, held until the process exits, so parallel test runs and demos never hear each other.
Child processes inherit the environment and hence the domain.
"""
from __future__ import annotations

import fcntl
import os
from pathlib import Path
import tempfile

# Fast DDS maps a domain to UDP ports 7400 + 250 * id; ids up to 101 stay below the ephemeral
# port range on Linux. Domain 0 is left to whatever else runs on the machine.
DOMAIN_IDS = range(1, 102)
_held_locks: dict[int, object] = {}


def _lock_dir() -> Path:
    path = Path(tempfile.gettempdir()) / 'mantis_rig_ros_domains'
    path.mkdir(exist_ok=True)
    return path


def claim_free_domain() -> int:
    """Lock and return a ROS domain id that no other process on this machine has claimed.

    Of the free ids it takes the one used longest ago, by any process (a lock file's
    modification time marks its last claim and release): participants of a process that ended
    without cleaning up (SIGKILL, os._exit) stay in a domain's discovery until their lease runs
    out, and the next test in that domain, in this process or a parallel one, would see their
    services (a ghost /stage_node/get_state that never answers)."""
    lock_dir = _lock_dir()

    def last_used(domain: int) -> float:
        try:
            return (lock_dir / f'domain_{domain}.lock').stat().st_mtime
        except FileNotFoundError:
            return 0.0

    for domain in sorted(DOMAIN_IDS, key=last_used):
        path = lock_dir / f'domain_{domain}.lock'
        handle = open(path, 'a')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        os.utime(path)
        _held_locks[domain] = handle
        return domain
    raise RuntimeError(f'every ROS domain id in {DOMAIN_IDS.start}..{DOMAIN_IDS.stop - 1} is '
                       f'claimed by another process on this machine')


def release_domain(domain: int) -> None:
    """Give back a domain this process claimed (no-op for one it does not hold)."""
    handle = _held_locks.pop(domain, None)
    if handle is not None:
        os.utime(handle.name)           # released now: the last to be claimed again
        handle.close()


def claim_local_domain(env: dict | None = None) -> dict:
    """Make `env` (default os.environ) keep DDS on loopback, on a free domain if none is set."""
    env = os.environ if env is None else env
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if not env.get('ROS_DOMAIN_ID'):
        env['ROS_DOMAIN_ID'] = str(claim_free_domain())
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    return env
