"""Files written whole or not at all: a crash or a full disk leaves the old file or the new one,
never a part (the rig's bag metadata, a study's record, a film's folder, a sweep's table)."""
from __future__ import annotations

import os
from pathlib import Path


def fsync_dir(directory) -> None:
    """fsync a directory so that new entries in it survive a crash (best effort: a file system
    that cannot sync a directory is left as it is)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_atomically(path, data, temp_name: str | None = None) -> Path:
    """Write ``data`` (text or bytes) to ``path`` through a temporary file beside it (named
    ``temp_name``, default ``.<name>.tmp``), synced, renamed over ``path`` and the rename
    synced; ``path``."""
    path = Path(path)
    temp = path.with_name(temp_name or f'.{path.name}.tmp')
    binary = isinstance(data, (bytes, bytearray))
    with open(temp, 'wb' if binary else 'w', **({} if binary else {'encoding': 'utf-8'})) \
            as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temp, path)
    fsync_dir(path.parent)
    return path


__all__ = ['fsync_dir', 'write_atomically']
