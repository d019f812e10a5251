"""What a herd recording implies for the live graph: datum, clock, field, fence, robots, rate.

``herd-ros demo --bag ANY_BAG`` needs no tuning flags: everything that used to be a constant of
the shipped synthetic paddock is derived here from the fixes themselves, by the offline ingest
(:mod:`herd_ros.ingest.pipeline`, the same numerics as the ``gps_ingest`` node), so outlier
bursts and silent collars cannot inflate the region or the speeds:

* **datum**: the median latitude/longitude of the valid fixes (the centre of the herd's range,
  robust to outliers; altitude 0);
* **dt** (the model's step): the median fix interval, rounded to a round step
  (:func:`~herd_ros.ingest.pipeline.auto_dt`), and at least ``min_dt`` (the live demo asks
  for :data:`LIVE_MIN_DT`); ``stale_after`` and ``reinit_after_gap`` from the fix intervals
  too (:func:`~herd_ros.ingest.pipeline.auto_filter_params`); **clock_dt** (the step of
  ``/herd/poses``): the largest round step that divides dt, is at least ``min_dt`` and
  :data:`LIVE_MIN_DT` and at most the track's clock
  (:func:`~herd_ros.ingest.pipeline.track_dt`), so that each fix of a duty-cycled collar is
  in ``/herd/poses`` within a step while the estimator learns at dt (it skips the snapshots
  in between); dt itself where none is finer (1 Hz collars);
* **field bounds**: the region the filtered herd visited, with a margin of 10 % of its extent
  (at least 10 m); **field grid**: about :data:`FIELD_CELLS` cells of equal spacing over it,
  and no more than one cell per :data:`SAMPLES_PER_FIELD_CELL` herd-clock steps of an
  animal (each cell adds two parameters per animal; a field with more cells than the data
  support over-fits, and robots driven by it wander off: the synthetic cows' hour on a 20 s
  clock, 180 steps, with 12 cells simulated robots 70 % farther apart than the cows, with
  4 cells 17 %);
* **fence**: the field bounds, so the robots have the animals' range and a little more
  (a second margin beyond them, as before, gave the robots of ten penned calves 1.48 × the
  area: in the live demo on the calves' RTLS bag their mean distance came out +71 % of the
  calves', against +48 and +58 % in two runs with the field bounds; the baboons' demo
  the same, +7 / +2 / +1 / −3 %);
* **robots**: one per animal, starting where its animal was first seen; their speed limit is
  1.5 × the 99th percentile of the animals' filtered speeds (0.5-5 m/s);
* **law**: the paper's pairwise law for up to :data:`PAIRWISE_MAX_AGENTS` animals, the shared
  interaction law for more: the pairwise law has 2(N − 1) pair parameters per animal, most of
  them not identified from hours of data, and their errors add up over the neighbours (the
  baboons' pairwise law simulates robots 5 × faster than the animals, measured, against
  about +25 % for the shared law); the shared law's radius is 4 × the median
  nearest-neighbour distance (10-200 m);
* **rate**: so that the replay takes about ``target_wall_s`` (four minutes by default).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from herd_ros.errors import HerdInputError
from herd_ros.estimation.model_selection import PAIRWISE_MAX_AGENTS, typical_spacing

#: Field cells over the visited region (about; the grid follows its aspect ratio).
FIELD_CELLS = 12
#: Herd-clock steps of data an animal needs per field cell (20 samples per field parameter).
SAMPLES_PER_FIELD_CELL = 40
#: Replay so that the bag takes about this long (s of wall time). At two minutes (rate 30
#: for the baboons' hour) a 2-core machine about twice as slow in Python lost most collars
#: to staleness (a median of 1-2 of the 19 animals in a herd pose) until gps_ingest's
#: ``silence_grace_s``; with it all 19 are there at rate 30 too, but the controller and the
#: fleet lag (robots' speed +18 %, 16 of 19 passing), against 18-19 of 19 at four minutes.
TARGET_WALL_S = 240.0
#: Shortest herd clock of the live demo (s). The composed graph replays an hour in two
#: minutes in one Python process; with 19 baboons on a 1 s clock it saturated a core and
#: lost about half of the animal-ticks to stale collars, and the law learned at 1 s drove the
#: robots 30-80 % off the animals' statistics; at 5 s nothing was lost and all four
#: statistics were within 20 % (measured on bags/baboons_1h). Motion at 1 s is mostly
#: filter smoothing: a step of a few seconds is what the model can learn from.
LIVE_MIN_DT = 5.0


@dataclass
class HerdSetup:
    """Everything the live graph needs to know about one herd recording."""

    agents: list[str]
    datum: list[float]                    # lat, lon, alt
    dt: float                             # herd clock step (s)
    stale_after: float                    # s of data time
    reinit_after_gap: float               # s
    field_grid: list[int]                 # nx, ny
    field_bounds: list[float]             # xmin, xmax, ymin, ymax (m)
    fence: list[list[float]]              # polygon [[x, y], ...] (m)
    robots: list[str]
    robot_start: list[list[float]]        # [[x, y], ...] (m), one per robot
    robot_max_speed: float                # m/s
    law: str                              # 'pairwise' or 'shared'
    interaction_radius: float             # m (shared law)
    duration_s: float                     # data time spanned by the fixes
    rate: float                           # replay speed-up
    notes: dict = field(default_factory=dict)
    clock_dt: float = 0.0                 # /herd/poses step (s), dividing dt; 0 = dt

    @property
    def clock(self) -> float:
        """The step of ``gps_ingest``'s herd clock (/herd/poses): :attr:`clock_dt`, or the
        model's step ``dt`` when none is set."""
        return float(self.clock_dt) if self.clock_dt and self.clock_dt > 0 else float(self.dt)

    def to_dict(self) -> dict:
        """Plain types, for the herd file and summary.json."""
        return asdict(self)

    def describe(self) -> str:
        """What was chosen, one line per item (the demo prints it)."""
        b = self.field_bounds
        derived = 'herd_file' not in self.notes          # from the data, not a herd file
        datum = (f'lat {self.datum[0]:.7f} lon {self.datum[1]:.7f}'
                 + (' (median of the valid fixes)' if derived else '')
                 if self.datum else 'the first valid fix')
        clock = f'  herd clock: dt {self.dt:g} s'
        if self.clock != self.dt:
            clock = (f'  herd clock: /herd/poses every {self.clock:g} s (each fix in it within '
                     f'a step), the law learned at dt {self.dt:g} s')
        if derived:
            clock += (f' (median fix interval '
                      f'{self.notes.get("median_fix_interval_s", float("nan")):.3g} s, live '
                      f'clock at least {LIVE_MIN_DT:g} s)')
        fence = (f'{len(self.fence)}-gon' + (', the field bounds' if derived
                                            else '') if len(self.fence) else 'none')
        return '\n'.join([
            f'  herd: {len(self.agents)} animals over {self.duration_s / 3600:.1f} h of data',
            f'  datum: {datum}',
            clock + f'; stale after {self.stale_after:.0f} s',
            f'  field: {self.field_grid[0]} x {self.field_grid[1]} centres over x '
            f'[{b[0]:.0f}, {b[1]:.0f}] m, y [{b[2]:.0f}, {b[3]:.0f}] m'
            + (' (visited region)' if derived else ''),
            f'  fence: {fence}',
            f'  law: {self.law}' + (f' (radius {self.interaction_radius:.0f} m)'
                                    if self.law == 'shared' else ''),
            f'  robots: {len(self.robots)}, max speed {self.robot_max_speed:.2f} m/s',
            f'  replay: rate {self.rate:g} (about {self.duration_s / self.rate:.0f} s)'])


def _margin(lo, hi, fraction=0.1, least=10.0):
    return max(least, fraction * (hi - lo))


def divides(step: float, dt: float) -> bool:
    """Whether a clock of ``step`` ticks at every multiple of ``dt`` (dt / step whole)."""
    return 0 < step <= dt * (1 + 1e-12) and abs(dt / step - round(dt / step)) < 1e-9


def herd_clock_step(dt: float, track: float, min_dt: float = 0.0) -> float:
    """The step of /herd/poses for a model step ``dt``: the largest round step
    (:data:`~herd_ros.ingest.pipeline.NICE_STEPS`) that divides ``dt``, is at least
    ``min_dt`` and at most ``track`` (the track's clock); ``dt`` when there is none."""
    from herd_ros.ingest.pipeline import NICE_STEPS
    ok = [c for c in NICE_STEPS if max(min_dt, 0.0) <= c <= min(dt, track) + 1e-9
          and divides(c, dt)]
    return float(max(ok)) if ok else float(dt)


def herd_setup_from_fixes(fixes: pd.DataFrame, *, dt: float | None = None,
                          rate: float | None = None, min_dt: float = 0.0,
                          target_wall_s: float = TARGET_WALL_S) -> HerdSetup:
    """Derive a :class:`HerdSetup` from a fixes table (see the module docstring)."""
    from herd_ros.ingest.pipeline import (auto_dt, auto_filter_params, fix_intervals,
                                          track_dt, trajectory_from_fixes, valid_fix_mask)
    from herd_ros.io.gps_files import normalise_fixes

    fixes = normalise_fixes(fixes)
    valid = valid_fix_mask(fixes)
    if valid.sum() < 3:
        raise HerdInputError('fewer than three valid fixes: nothing to set a herd up from')
    datum = [float(np.median(fixes['lat'].to_numpy()[valid])),
             float(np.median(fixes['lon'].to_numpy()[valid])), 0.0]
    dt = float(dt) if dt is not None else max(auto_dt(fixes), float(min_dt))
    clock_dt = herd_clock_step(dt, track_dt(fixes), max(float(min_dt), LIVE_MIN_DT))
    filt = auto_filter_params(fixes)
    traj = trajectory_from_fixes(fixes, dt=dt, datum=datum, trim=True, **filt)
    p = traj.positions
    have = np.isfinite(p).all(axis=-1)
    pts = p[have]
    if len(pts) < 3:
        raise HerdInputError('the filtered herd has fewer than three positions')
    xmin, ymin = pts.min(axis=0)
    xmax, ymax = pts.max(axis=0)
    mx, my = _margin(xmin, xmax), _margin(ymin, ymax)
    bounds = [float(xmin - mx), float(xmax + mx), float(ymin - my), float(ymax + my)]
    w, h = bounds[1] - bounds[0], bounds[3] - bounds[2]
    steps_per_animal = float(np.median(have.sum(axis=0)))
    cells = int(np.clip(steps_per_animal // SAMPLES_PER_FIELD_CELL, 1, FIELD_CELLS))
    nx = int(np.clip(round(np.sqrt(cells * w / h)), 1, cells))
    ny = int(np.clip(round(cells / nx), 1, cells))
    x0, x1, y0, y1 = bounds
    fence = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    start = []
    for i in range(traj.n_agents):
        k = int(np.argmax(have[:, i])) if have[:, i].any() else None
        start.append([float(v) for v in (p[k, i] if k is not None else pts.mean(axis=0))])
    steps = np.diff(p, axis=0)
    speed = np.hypot(steps[..., 0], steps[..., 1]) / dt
    speed = speed[np.isfinite(speed)]
    v99 = float(np.percentile(speed, 99)) if len(speed) else 1.0
    spacing = typical_spacing([p])   # median nearest-neighbour distance (≤ 2000 ticks)
    times = fixes['time'].to_numpy(float)[valid]
    duration = float(times.max() - times.min())
    if rate is None:
        rate = max(1.0, float(f'{duration / target_wall_s:.2g}'))
    agents = list(traj.agents)
    return HerdSetup(
        agents=agents, datum=datum, dt=dt, stale_after=float(filt['stale_after']),
        reinit_after_gap=float(filt['reinit_after_gap']), field_grid=[nx, ny],
        field_bounds=bounds, fence=fence, robots=[f'robot_{k + 1}' for k in range(len(agents))],
        robot_start=start, robot_max_speed=float(np.clip(1.5 * v99, 0.5, 5.0)),
        law='pairwise' if len(agents) <= PAIRWISE_MAX_AGENTS else 'shared',
        interaction_radius=float(np.clip(4.0 * spacing, 10.0, 200.0)),
        duration_s=duration, rate=float(rate), clock_dt=clock_dt,
        notes={'median_fix_interval_s': float(np.median(fix_intervals(fixes))),
               'speed_p99_m_s': v99, 'median_nearest_neighbour_m': spacing,
               'visited_region': [float(xmin), float(xmax), float(ymin), float(ymax)]})
