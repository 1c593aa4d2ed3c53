"""What a trial's bag says: force stream continuity, phases, peak, and whether the camera
window caught the release (for `mantis trial` and the tests)."""
from __future__ import annotations

from dataclasses import dataclass, field
import math

from mantis_rig import contract
from mantis_rig.recording import TRIAL_CONDITIONS, TRIAL_OUTCOME, BagReader
from mantis_rig.recording.force_block import force_block_from_msg
from mantis_rig.recording.marker_block import concatenate, marker_block_from_msg
from mantis_rig.trial.force_monitor import ForceMonitor


@dataclass
class TrialSummary:
    path: str
    complete: bool
    outcome: dict
    conditions: dict
    topic_counts: dict
    force_samples: int = 0
    force_rate_hz: float = 0.0
    force_start_s: float = math.nan
    force_duration_s: float = 0.0
    force_gaps: list = field(default_factory=list)
    peak_force_n: float = math.nan
    peak_force_s: float = math.nan
    release_s: float | None = None       # first 1 ms jump of the force after the pull started
    states: list = field(default_factory=list)      # (state, log time s)
    trigger_s: float | None = None
    marker_span_s: tuple | None = None
    marker_frames: int = 0
    namespace: str = '/'      # the rig's, in which the bag's topics were recorded

    def state_time(self, state: str) -> float | None:
        return next((t for s, t in self.states if s == state), None)

    @property
    def release_caught(self) -> bool | None:
        if self.release_s is None or self.marker_span_s is None:
            return None
        return self.marker_span_s[0] <= self.release_s <= self.marker_span_s[1]


def summarize(path, release_jump_n: float = 1.0) -> TrialSummary:
    reader = BagReader(path, warn=False)
    summary = TrialSummary(
        path=str(path), complete=reader.complete,
        outcome=reader.metadata(TRIAL_OUTCOME) or {},
        conditions=reader.metadata(TRIAL_CONDITIONS) or {},
        topic_counts={name: info.message_count for name, info in reader.topics.items()})
    summary.namespace = contract.bag_namespace(reader.topics)
    wanted = (contract.FORCE_BLOCK, contract.MARKERS, contract.SUPERVISOR_STATE,
              contract.TRIGGER_TIME)
    by_name = {contract.resolve(topic, summary.namespace): topic for topic in wanted}
    blocks, markers = [], []
    for message in reader.messages(list(by_name)):     # not the wrenches and joint states
        t_s = message.log_time_ns * 1e-9
        topic = by_name.get(message.topic)
        if topic is contract.FORCE_BLOCK:
            blocks.append(force_block_from_msg(message.message))
        elif topic is contract.MARKERS:
            markers.append(marker_block_from_msg(message.message))
        elif topic is contract.SUPERVISOR_STATE:
            summary.states.append((message.message.data, t_s))
        elif topic is contract.TRIGGER_TIME and summary.trigger_s is None:
            stamp = message.message.header.stamp
            summary.trigger_s = stamp.sec + stamp.nanosec * 1e-9
    _force(summary, sorted(blocks, key=lambda b: b.t0_s), release_jump_n)
    if markers:
        frames = concatenate(sorted(markers, key=lambda m: m.time_s[0]))
        summary.marker_frames = len(frames)
        summary.marker_span_s = (float(frames.time_s[0]), float(frames.time_s[-1]))
    return summary


def _force(summary: TrialSummary, blocks, release_jump_n: float) -> None:
    if not blocks:
        return
    monitor = ForceMonitor(ceiling_n=math.inf, release_jump_n=release_jump_n)
    pull_s = summary.state_time('pulling')
    for block in blocks:
        if pull_s is not None and block.t0_s >= pull_s:
            monitor.arm_release()
        monitor.feed(block.t0_s, block.period_s, block.force_n)
    summary.force_samples = monitor.samples
    summary.force_rate_hz = 1.0 / monitor.period_s
    summary.force_start_s = monitor.first_t_s
    summary.force_duration_s = monitor.duration_s
    summary.force_gaps = monitor.gaps
    summary.peak_force_n, summary.peak_force_s = monitor.peak_n, monitor.peak_t_s
    summary.release_s = monitor.release_t_s


def format_summary(s: TrialSummary, with_path: bool = True) -> str:
    result = s.outcome.get('result', 'unknown (bag not closed)')
    lines = [f'bag: {s.path}' + ('' if s.complete else ' (not closed cleanly)')][:int(with_path)]
    lines += [f'outcome: {result}' + (f': {s.outcome["reason"]}' if s.outcome.get('reason')
                                     else '')]
    if s.force_samples:
        lines.append(f'force stream: {s.force_samples} samples at {s.force_rate_hz:.0f} S/s '
                     f'over {s.force_duration_s:.3f} s, {len(s.force_gaps)} gap(s)')
    if s.states:
        lines.append('phases (ROS time, s): ' + ', '.join(f'{state} {t:.3f}'
                                                          for state, t in s.states))
    pull_s = s.state_time('pulling')
    parts = []
    if pull_s is not None:
        parts.append(f'pull from {pull_s:.3f} s')
    if s.release_s is not None:
        parts.append(f'release at {s.release_s:.4f} s' + (
            f' (phases I-III {s.release_s - pull_s:.3f} s)' if pull_s is not None else ''))
    if s.force_samples:
        parts.append(f'peak force {s.peak_force_n:.2f} N at {s.peak_force_s:.4f} s')
    if parts:
        lines.append('seen from the force stream: ' + ', '.join(parts))
    if s.trigger_s is not None:
        window = (f'{s.marker_frames} marker frames {s.marker_span_s[0]:.4f}-'
                  f'{s.marker_span_s[1]:.4f} s' if s.marker_span_s else 'no marker frames')
        caught = {True: 'yes', False: 'NO', None: 'unknown'}[s.release_caught]
        lines.append(f'camera: trigger at {s.trigger_s:.4f} s, {window}; release caught: '
                     f'{caught}')
    lines.append('topics: ' + ', '.join(f'{t} {n}' for t, n in sorted(s.topic_counts.items())))
    return '\n'.join(lines)


def force_samples_expected(s: TrialSummary) -> float:
    """rate x duration of the recorded force stream (to compare with the sample count)."""
    return s.force_rate_hz * s.force_duration_s if s.force_samples else 0.0

