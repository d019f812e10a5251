"""Herd trajectories on one uniform clock, and the trajectory CSV format of doc/formats.md.

A :class:`HerdTrajectory` is one run: ``positions[t, i] = (x, y)`` of agent ``agents[i]`` at
``times[t]``, metres east/north in the local ENU frame. Independent recordings are separate
runs (the CSV's optional ``run`` column); each run has its own clock.

The CSV header is ``time,agent,x,y`` (optionally ``run``). :func:`read_trajectory_csv`
checks everything the fit relies on and raises :class:`HerdInputError` with the file, line
and field at fault: missing columns, NaN/inf, unsorted or duplicate time stamps, a clock that is
not uniform. An agent without a row at some step of the clock (a stale collar) is missing
there: its position is NaN, and the fit skips what needs it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.io.csv_bytes import fixed_point, join_rows, text_field

REQUIRED_COLUMNS = ('time', 'agent', 'x', 'y')


@dataclass
class HerdTrajectory:
    """One run of a herd on a uniform clock.

    Attributes:
        times: (T,) seconds, uniformly spaced by ``dt``.
        agents: N agent ids, in column order of ``positions``.
        positions: (T, N, 2) metres (x east, y north).
        run: the run label (``None`` for a file without a ``run`` column).
    """

    times: np.ndarray
    agents: list[str]
    positions: np.ndarray
    run: str | None = None
    meta: dict = field(default_factory=dict)

    @property
    def dt(self) -> float:
        """The clock step (s)."""
        if len(self.times) < 2:
            raise HerdInputError(f'run {self.run!r} has fewer than two time steps')
        return float(np.median(np.diff(self.times)))

    @property
    def n_steps(self) -> int:
        """Number of clock steps T."""
        return int(self.positions.shape[0])

    @property
    def n_agents(self) -> int:
        """Number of agents N."""
        return int(self.positions.shape[1])

    def slice(self, start: int, stop: int) -> 'HerdTrajectory':
        """The steps ``start:stop`` of this run (a view of the same arrays)."""
        return HerdTrajectory(self.times[start:stop], list(self.agents),
                              self.positions[start:stop], self.run, dict(self.meta))


def clock_is_uniform(times, tol: float = 1e-3) -> bool:
    """Every step between the sorted distinct ``times`` is a whole number of the median step
    (within ``tol`` of it): a uniform clock, possibly with whole steps missing."""
    t = np.unique(np.asarray(times, dtype=float))
    if len(t) < 3:
        return False
    steps = np.diff(t)
    ratio = steps / float(np.median(steps))
    whole = np.rint(ratio)
    return bool((whole >= 1).all() and (np.abs(ratio - whole) / whole <= tol).all())


def _fail(path, msg):
    raise HerdInputError(f'{path}: {msg}')


def read_trajectory_csv(path, *, uniform_tolerance: float = 1e-3,
                        require_uniform: bool = True) -> list[HerdTrajectory]:
    """Read a trajectory CSV into one :class:`HerdTrajectory` per run.

    Args:
        path: the CSV file.
        uniform_tolerance: largest allowed deviation of a step from the run's median step,
            as a fraction of that step.
        require_uniform: check that every agent has a row at every time of its run and that
            the clock is uniform (what the herd model needs). With ``False`` the rows are
            only parsed and checked for order and NaN.

    Raises:
        HerdInputError: one line naming the file, the line (1-based, header = 1) and why.
    """
    import pandas as pd

    from herd_ros.io.csv_text import check_csv_text

    path = Path(path)
    check_csv_text(path)
    try:
        df = pd.read_csv(path, dtype={'agent': str, 'run': str}, skipinitialspace=True)
    except Exception as exc:  # pandas raises many kinds; say it once
        _fail(path, f'not a readable CSV ({exc.__class__.__name__}: {exc})'.splitlines()[0])
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        _fail(path, f'missing column(s) {", ".join(missing)}; the header must be '
                    f'time,agent,x,y[,run] (got {",".join(df.columns)})')
    if len(df) == 0:
        _fail(path, 'no data rows')
    for col in ('time', 'x', 'y'):
        values = pd.to_numeric(df[col], errors='coerce').to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            k = int(np.argmax(bad))
            _fail(path, f'line {k + 2}: {col} is {df[col].iloc[k]!r}, not a finite number')
        df[col] = values
    if df['agent'].isna().any():
        k = int(np.argmax(df['agent'].isna().to_numpy()))
        _fail(path, f'line {k + 2}: empty agent id')
    from herd_ros.agent_ids import ros_agent_id_column
    df['agent'] = ros_agent_id_column(df['agent'], str(path))
    has_run = 'run' in df.columns
    if has_run:
        df['run'] = df['run'].fillna('')
    df['_line'] = np.arange(len(df)) + 2
    runs = []
    groups = df.groupby('run', sort=False) if has_run else [(None, df)]
    for run_label, rdf in groups:
        runs.append(_build_run(path, run_label, rdf, uniform_tolerance, require_uniform))
    return runs


def _build_run(path, run_label, rdf, tol, require_uniform) -> HerdTrajectory:
    where = f' (run {run_label})' if run_label is not None else ''
    # sorted, as the fix readers give them: the same herd in another row order (a track
    # written by `herd-ros ingest` starts with the agents that have a pose at the first
    # tick) is the same herd, down to which noise stream a simulation gives each agent
    agents = sorted(set(rdf['agent'].tolist()))
    per_agent = {}
    for agent, adf in rdf.groupby('agent', sort=False):
        t = adf['time'].to_numpy()
        d = np.diff(t)
        if (d < 0).any():
            k = int(np.argmax(d < 0)) + 1
            _fail(path, f'line {adf["_line"].iloc[k]}: rows of agent {agent}{where} are not '
                        f'sorted by time ({t[k]} after {t[k - 1]})')
        if (d == 0).any():
            k = int(np.argmax(d == 0)) + 1
            _fail(path, f'line {adf["_line"].iloc[k]}: duplicate time {t[k]} for agent '
                        f'{agent}{where}')
        per_agent[agent] = adf
    if not require_uniform:
        times = np.unique(rdf['time'].to_numpy())
        pos = np.full((len(times), len(agents), 2), np.nan)
        for i, a in enumerate(agents):
            adf = per_agent[a]
            idx = np.searchsorted(times, adf['time'].to_numpy())
            pos[idx, i, 0] = adf['x'].to_numpy()
            pos[idx, i, 1] = adf['y'].to_numpy()
        return HerdTrajectory(times, agents, pos, run_label)
    times = np.unique(rdf['time'].to_numpy())
    if len(times) < 3:
        _fail(path, f'run{where or ""} has {len(times)} time steps; at least 3 are needed')
    steps = np.diff(times)
    dt = float(np.median(steps))
    # a missing agent (no row) is a gap in its track; ticks nobody has are whole missing
    # steps: both are fine on a uniform clock (positions NaN), any other step is not
    ratio = steps / dt
    whole = np.rint(ratio)
    dev = np.abs(ratio - whole) / np.maximum(whole, 1.0)
    if (dev > tol).any() or (whole < 1).any():
        k = int(np.argmax((dev > tol) | (whole < 1)))
        _fail(path, f'the clock{where} is not uniform: step {steps[k]:g} s at time '
                    f'{times[k + 1]:g} vs the usual {dt:g} s; resample with `herd-ros ingest` '
                    f'or split the recording with a run column')
    index = np.concatenate([[0], np.cumsum(whole.astype(int))])
    grid = times[0] + dt * np.arange(index[-1] + 1)
    grid[index] = times
    pos = np.full((len(grid), len(agents), 2), np.nan)
    for i, a in enumerate(agents):
        adf = per_agent[a]
        k = index[np.searchsorted(times, adf['time'].to_numpy())]
        pos[k, i, 0] = adf['x'].to_numpy()
        pos[k, i, 1] = adf['y'].to_numpy()
    return HerdTrajectory(grid, agents, pos, run_label)


def write_trajectory_csv(path, runs: list[HerdTrajectory] | HerdTrajectory,
                         float_format: str = '%.6f') -> Path:
    """Write runs as a trajectory CSV (``time,agent,x,y`` and ``run`` if there are several
    runs or any run is labelled). Rows are ordered by run, time, then agent; an agent-tick
    without a finite position has no row."""
    if isinstance(runs, HerdTrajectory):
        runs = [runs]
    with_run = len(runs) > 1 or any(r.run is not None for r in runs)
    labels = [str(r.run) if r.run is not None else str(k) for k, r in enumerate(runs)]
    columns = (['run'] if with_run else []) + ['time', 'agent', 'x', 'y']
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = {str(a) for r in runs for a in r.agents} | {str(r.run) for r in runs}
    plain = not any(ch in name for name in names for ch in ',"\r\n\0')
    fixed = re.fullmatch(r'%\.(\d+)f', float_format)
    if plain and fixed:     # column-wise in numpy (csv_bytes): the same text as pandas'
        # to_csv in a tenth of its time (360 000 rows: 0.11-0.16 s against 1.4 s)
        decimals = int(fixed.group(1))
        with open(path, 'wb') as fh:
            fh.write((','.join(columns) + '\n').encode())
            for label, r in zip(labels, runs):
                T, N = r.positions.shape[:2]
                pos = np.asarray(r.positions, dtype=float).reshape(T * N, 2)
                rows = np.flatnonzero(np.isfinite(pos).all(axis=1))
                if not len(rows):
                    continue
                tick, agent = np.divmod(rows, N)       # few ticks and names, each made once
                fields = []
                if with_run:
                    buf, _ = text_field([label])
                    fields.append((np.broadcast_to(buf, (len(rows), buf.shape[1])), None))
                buf, _ = fixed_point(np.asarray(r.times, dtype=float), decimals)
                fields.append((buf[tick], None))
                buf, _ = text_field([str(a) for a in r.agents])
                fields.append((buf[agent], None))
                fields.append(fixed_point(pos[rows, 0], decimals))
                fields.append(fixed_point(pos[rows, 1], decimals))
                fh.write(join_rows(fields))
        return path
    import pandas as pd

    frames = []
    for label, r in zip(labels, runs):
        T, N = r.positions.shape[:2]
        frame = pd.DataFrame({
            'time': np.repeat(r.times, N),
            'agent': np.tile(np.asarray(r.agents, dtype=object), T),
            'x': r.positions[:, :, 0].ravel(),
            'y': r.positions[:, :, 1].ravel(),
        })
        frame = frame[np.isfinite(frame['x']) & np.isfinite(frame['y'])]
        if with_run:
            frame.insert(0, 'run', label)
        frames.append(frame)
    pd.concat(frames).to_csv(path, index=False, float_format=float_format)
    return path
