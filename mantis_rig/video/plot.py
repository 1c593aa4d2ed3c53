"""`mantis track --plot`: the recording's first frame with the markers found on it, each named,
and the path each marker took through the recording (image pixels)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .recording import open_recording
from .track import Tracks


def plot_tracks(video, tracks: Tracks, path, rate_hz=None) -> Path:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    with open_recording(video, rate_hz) as recording:
        first = next(iter(recording.frames(0, 1))).image
    height, width = first.shape[:2]
    scale = 7.0 / max(height, width)
    fig, ax = plt.subplots(figsize=(max(width * scale, 3.0) + 1.2, max(height * scale, 3.0)))
    ax.imshow(first, cmap='gray', vmin=0, vmax=np.iinfo(first.dtype).max
              if first.dtype.kind in 'ui' else None)
    colours = plt.get_cmap('tab10')
    for k, name in enumerate(tracks.names):
        xy = tracks.xy_px[name]
        colour = colours(k % 10)
        ax.plot(xy[:, 0], xy[:, 1], '-', color=colour, linewidth=1.0, alpha=0.8)
        seen = np.flatnonzero(np.isfinite(xy[:, 0]))
        if seen.size:
            x, y = xy[seen[0]]
            ax.plot([x], [y], 'o', markersize=9, markerfacecolor='none', color=colour)
            ax.annotate(name, (x, y), xytext=(6, -6), textcoords='offset points', color=colour,
                        fontsize=10, fontweight='bold')
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_xlabel('image x (pixels, right)')
    ax.set_ylabel('image y (pixels, down)')
    ax.set_title(f'{Path(str(video)).name}: the markers on its first frame and their paths '
                 f'over {len(tracks.index)} frames', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


__all__ = ['plot_tracks']
