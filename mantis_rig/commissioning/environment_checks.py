"""The ROS environment `mantis doctor` runs in (domain, discovery range, middleware) and the
free disk space where trials are written."""
from __future__ import annotations

import os
from pathlib import Path
import shutil

from .check_report import FAIL, OK, WARN, Report

DISK_FAIL_BYTES = 1 << 30
DISK_WARN_BYTES = 10 << 30


def check_ros_environment(report: Report, env=None) -> None:
    env = os.environ if env is None else env
    domain = env.get('ROS_DOMAIN_ID', '')
    if not domain:
        report.add('ros: domain', WARN, 'ROS_DOMAIN_ID is unset: domain 0, shared with every '
                   'ROS 2 program on the network', 'export ROS_DOMAIN_ID=N, a number of this '
                   'rig\'s own in 1..101 (`. scripts/ros_env.sh` picks a free one)')
    elif not domain.isdigit() or not 0 <= int(domain) <= 232:
        report.add('ros: domain', FAIL, f'ROS_DOMAIN_ID={domain!r} is not a domain id '
                   f'(0..232)', 'export ROS_DOMAIN_ID=N with N in 1..101')
    else:
        report.add('ros: domain', OK, f'ROS_DOMAIN_ID={domain}')
    scope = env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '')
    if scope.upper() == 'LOCALHOST':
        report.add('ros: discovery range', OK, 'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: DDS '
                   'stays on this machine')
    else:
        shown = f'={scope}' if scope else ' is unset (SUBNET)'
        report.add('ros: discovery range', WARN, f'ROS_AUTOMATIC_DISCOVERY_RANGE{shown}: DDS '
                   f'discovery may leave this machine and other hosts may command the rig',
                   'export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (`. scripts/ros_env.sh`), '
                   'unless another machine must see the rig')
    rmw = env.get('RMW_IMPLEMENTATION', '')
    try:
        from rclpy.utilities import get_rmw_implementation_identifier
        loaded = get_rmw_implementation_identifier()
    except Exception as exc:  # noqa: BLE001 - a diagnosis: whatever loading rclpy's middleware raises is the finding, reported FAIL
        report.add('ros: middleware', FAIL, f'rclpy cannot load the middleware '
                   f'{rmw or "(default)"}: {" ".join(str(exc).split())}',
                   'reinstall with ./scripts/bootstrap.sh, or export '
                   'RMW_IMPLEMENTATION=rmw_fastrtps_cpp')
        return
    report.add('ros: middleware', OK, f'{loaded}' + ('' if rmw else ' (RMW_IMPLEMENTATION '
                                                     'unset: the default)'))


def _existing_parent(path: Path) -> Path:
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_disk(report: Report, out: Path) -> None:
    where = _existing_parent(out)
    try:
        usage = shutil.disk_usage(where)
    except OSError as exc:
        report.add('disk', FAIL, f'cannot read the free space at {where}: {exc.strerror}',
                   'set the supervisor\'s out parameter to a writable directory')
        return
    free_gib = usage.free / (1 << 30)
    found = f'{free_gib:.1f} GiB free where trials are written ({out})'
    if not os.access(where, os.W_OK):
        report.add('disk', FAIL, f'{found}, but {where} is not writable by this user',
                   f'make {where} writable or set the supervisor\'s out parameter elsewhere')
    elif usage.free < DISK_FAIL_BYTES:
        report.add('disk', FAIL, found, 'free space on that disk (a trial\'s bag takes tens '
                   'of MB) or set out to another disk')
    elif usage.free < DISK_WARN_BYTES:
        report.add('disk', WARN, found, 'free space soon: under 10 GiB left')
    else:
        report.add('disk', OK, found)


__all__ = ['check_disk', 'check_ros_environment']
