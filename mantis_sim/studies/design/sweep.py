"""`mantis sweep`: many simulated strikes, one row per design, in a Parquet table.

The designs (`designs`) go out in chunks, so that scheduling costs little against a
strike of a few ms: to a dask.distributed LocalCluster on this machine's cores (embedded, no
server to start; it listens on 127.0.0.1 only), to an existing cluster (``scheduler``
``tcp://HOST:PORT``), or, with ``workers=0``, through this process alone. A design is computed
the same way wherever it runs, so the three give the same table to the last digit.

Resumable: the table is rewritten (to a temporary file, then renamed) every
``CHECKPOINT_S`` of wall time and at the end; a rerun with the same ``out`` computes only the
designs it lacks. A worker lost in mid-sweep costs nothing but time: dask reruns its chunks.
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import time

from mantis_sim.errors import InputError
from mantis_sim.results import force_warnings
from mantis_sim.studies.design.designs import ID_COLUMN, SPREAD_ROBOTS_COLUMN, STATUS_OK, run_chunk
from mantis_sim.studies.shared.parallel import Progress, connect

CHECKPOINT_S = 10.0
CHUNK_TARGET_S = 0.2            # wall time of one chunk: scheduling costs ~ms per task
CHUNKS_PER_WORKER = 10          # at least: the last chunk is the sweep's tail
# A design whose peak tendon force is beyond the load cell's range (mantis_sim.results
# .force_warnings) says so here; '' otherwise.
WARNING_COLUMN = 'warning'


class SweepError(InputError):
    """The sweep cannot start as asked (names the problem)."""


@dataclass
class SweepSummary:
    designs: int                 # in the study
    computed: int                # this run
    reused: int                  # from an earlier run's table
    ok: int
    wall_s: float                # computing, from a ready cluster to the last row
    strikes_s: float             # sum of the designs' own computing times (this run)
    workers: int
    where: str
    spread_robots: int = 0       # robots drawn per design (mantis sweep --spread)

    @property
    def overhead_share(self) -> float:
        """Share of the workers' wall time not spent on the designs themselves (scheduling,
        transfer, the table)."""
        busy = self.wall_s * max(self.workers, 1)
        return 1.0 - self.strikes_s / busy if busy > 0 else float('nan')

    def __str__(self) -> str:
        rate = self.computed / self.wall_s if self.wall_s > 0 else float('nan')
        if self.spread_robots:
            rate *= 1 + self.spread_robots
        robots = (f', each with {self.spread_robots} robots of its spread'
                  if self.spread_robots else '')
        return (f'{self.designs} designs{robots}: {self.computed} computed, {self.reused} from the '
                f'earlier table; {self.ok} struck, {self.designs - self.ok} without a strike '
                f'or failed (see status, reason); {self.wall_s:.1f} s wall on {self.where} '
                f'({self.workers} worker(s)): {rate:.0f} strikes/s; the designs themselves '
                f'{self.strikes_s:.1f} s, scheduling and transfer '
                f'{100 * self.overhead_share:.0f} % of the workers\' time')


def read_table(path: Path) -> list[dict]:
    """The rows of an earlier run (empty if there is none)."""
    import pyarrow.parquet as pq
    if not path.exists():
        return []
    try:
        return pq.read_table(path).to_pylist()
    except Exception as exc:      # noqa: BLE001 - pyarrow raises several kinds: name the file
        raise SweepError(f'{path}: exists but is not a readable Parquet table of a sweep '
                         f'({type(exc).__name__}: {exc}); move it away or give another '
                         f'--out') from None


def write_table(rows: list[dict], path: Path) -> None:
    """All rows, in design order, replacing the file atomically."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    columns = {}
    for row in rows:                      # every column any row has, in first-seen order
        for key in row:
            columns.setdefault(key, None)
    table = pa.Table.from_pylist([{k: row.get(k) for k in columns} for row in rows])
    tmp = path.with_name(path.name + '.partial')
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def chunk_size_for(estimated_strike_s: float, designs: int, workers: int) -> int:
    """Enough designs per chunk for ~CHUNK_TARGET_S of work, yet at least CHUNKS_PER_WORKER
    chunks a worker (so that the load balances, the workers finish together and a lost worker
    loses little)."""
    by_time = max(1, int(CHUNK_TARGET_S / max(estimated_strike_s, 1e-4)))
    by_balance = max(1, designs // (CHUNKS_PER_WORKER * max(workers, 1)))
    return max(1, min(by_time, by_balance))


def run_sweep(scene_name: str, overrides: list, designs: list[dict], out: Path, *,
              scheduler: str | None = None, workers: int | None = None,
              chunk_size: int | None = None, estimated_strike_s: float = 0.01,
              progress: bool = True, spread_robots: int = 0,
              spread_seed: int = 1) -> SweepSummary:
    """Compute the designs ``out`` lacks and write the table (module docstring). With
    ``spread_robots`` N, each row also holds its quantiles over N robots of the scene's spread
    (mantis_sim.studies.design.designs); an earlier row without them, or with another N or seed, is
    computed again."""
    from mantis_sim.scene import load_scene
    from mantis_sim.studies.design.designs import design_id
    out = Path(out)
    capacity_n = load_scene(scene_name, overrides).loadcell.capacity_N
    earlier = {row[ID_COLUMN]: _with_warning(row, capacity_n) for row in read_table(out)
               if (row.get(SPREAD_ROBOTS_COLUMN) or 0) == spread_robots
               and (not spread_robots or row.get('spread_seed') == spread_seed)}
    work = (spread_robots, spread_seed)
    estimated_strike_s *= 1 + spread_robots
    ids = [design_id(d) for d in designs]
    todo = [(i, d) for i, (i_d, d) in enumerate(zip(ids, designs)) if i_d not in earlier]
    rows = {i: earlier[i_d] for i, i_d in enumerate(ids) if i_d in earlier}
    started = time.monotonic()             # of the computing (after a cluster is up)
    bar = Progress(len(designs), len(rows)) if progress else None
    strikes_s = 0.0
    last_row = started

    def finished(chunk_rows, positions):
        nonlocal strikes_s, last_row
        for pos, row in zip(positions, chunk_rows):
            rows[pos] = _with_warning(row, capacity_n)
            strikes_s += float(row.get('design_time_s') or 0.0)
        last_row = time.monotonic()
        if bar:
            bar.advance(len(chunk_rows))

    last_checkpoint = time.monotonic()

    def checkpoint(force=False):
        nonlocal last_checkpoint
        if force or time.monotonic() - last_checkpoint >= CHECKPOINT_S:
            write_table([rows[i] for i in sorted(rows)], out)
            last_checkpoint = time.monotonic()

    try:
        if workers == 0 and scheduler is None:
            where, n_workers = 'this process', 1
            size = chunk_size or chunk_size_for(estimated_strike_s, len(todo), 1)
            for chunk in _chunks(todo, size):
                finished(run_chunk(scene_name, overrides, [d for _, d in chunk], *work),
                         [i for i, _ in chunk])
                checkpoint()
        else:
            client, cluster, where = connect(scheduler, workers)
            started = last_row = time.monotonic()
            try:
                n_workers = max(1, len(client.scheduler_info().get('workers', {})))
                size = chunk_size or chunk_size_for(estimated_strike_s, len(todo), n_workers)
                chunks = list(_chunks(todo, size))
                _run_on_cluster(client, scene_name, overrides, chunks, work, finished,
                                checkpoint)
            finally:
                client.close()
                if cluster is not None:
                    cluster.close()
    finally:
        if bar:
            bar.close()
        if len(rows) > len(earlier):
            checkpoint(force=True)
    ordered = [rows[i] for i in sorted(rows)]
    return SweepSummary(designs=len(designs), computed=len(todo), reused=len(designs) - len(todo),
                        ok=sum(r.get('status') == STATUS_OK for r in ordered),
                        wall_s=last_row - started, strikes_s=strikes_s,
                        workers=n_workers, where=where, spread_robots=spread_robots)


def _with_warning(row: dict, capacity_n: float) -> dict:
    """The row with its WARNING_COLUMN (the design's own load-cell range if it varies it)."""
    force = row.get('peak_tendon_force_N')
    capacity = row.get('loadcell.capacity_N', capacity_n)
    lines = force_warnings(capacity, force) if force is not None else []
    return {**row, WARNING_COLUMN: '; '.join(lines)}


def _chunks(items: list, size: int):
    for start in range(0, len(items), size):
        yield items[start:start + size]


def _run_on_cluster(client, scene_name, overrides, chunks, work, finished, checkpoint) -> None:
    from dask.distributed import as_completed
    futures = {}
    for chunk in chunks:
        future = client.submit(run_chunk, scene_name, overrides, [d for _, d in chunk], *work,
                               pure=False)
        futures[future] = [i for i, _ in chunk]
    for future in as_completed(futures):
        finished(future.result(), futures.pop(future))
        checkpoint()


__all__ = ['SweepError', 'SweepSummary', 'read_table', 'run_sweep', 'write_table']
