"""Free-run fidelity (issue 30): does the law, run freely, keep the herd's shape and pace?

One-step skill says how well the law predicts the next position from the true current one;
robots driven by the law never get the true positions back. So the law is also run freely
from the start of held-out data for its whole length, with its noise, several seeds, and
the held-out data and the runs are compared on statistics of shape and pace — per animal,
then the herd's mean over animals:

* ``distance``: mean over time of the animal's mean distance to the others (m);
* ``spread``: standard deviation over time of that distance (m);
* ``pace``: mean displacement over :data:`PACE_WINDOW_S` divided by that window (m/s) —
  collar noise barely touches it, unlike a speed at the clock step;
* ``mean_speed``, ``std_speed``: the paper's, ‖p^{τ+1} − p^τ‖/Δt between consecutive
  steps (Schwager, Anderson & Rus 2007, Fig. 6; :mod:`herd_ros.simulation.statistics`).

Each statistic of the runs is summarised by its median over seeds and the range (min, max),
and the median's relative difference to the data's.

**Like with like.** Every animal runs for the whole run, but the data miss animals: a
collar that starts late, stops for hours or ends early. A statistic over "the others" then
changes with who is present — when a collar 1.3 km from the herd falls silent, the others'
mean distance to the others drops by hundreds of metres, and the data's ``spread`` is mostly
that. So a run is observed as the data were (:func:`observed_like`): at each step, an animal
absent from the data is absent from the run, and both are compared over the run's span —
the observation process applied to the simulation, as in simulated-moment methods
(Gouriéroux, Monfort & Renault 1993). On 72-hour three-steer herds with one steer 1.3 km
off and duty-cycled collars (``test/bench/bench_free_run.py``), the data's spread is
148-186 m, the runs' 4-16 m seen whole and 148-186 m seen like the data.
"""
from __future__ import annotations

import numpy as np

from herd_ros.nan_stats import empty_slices_quiet
from herd_ros.trajectory import HerdTrajectory

STATISTICS = ('distance', 'spread', 'pace', 'mean_speed', 'std_speed')
#: the displacement window of ``pace`` (s): ten minutes
PACE_WINDOW_S = 600.0
#: noise seeds of a free run
SEEDS = 5


def shape_and_pace(positions: np.ndarray, dt: float, pace_window_s: float = PACE_WINDOW_S
                   ) -> dict[str, np.ndarray]:
    """Per animal (N,) each of :data:`STATISTICS` of ``positions`` (T, N, 2) on a clock of
    step ``dt`` (NaN = missing; a statistic with no data is NaN). The pace window is
    ``pace_window_s`` (at least one step: on a clock coarser than the window, the pace
    is the displacement per step) or, for a run shorter than two windows, a quarter of
    the run."""
    p = np.asarray(positions, dtype=float)
    T, n = p.shape[:2]
    d = np.sqrt(((p[:, None] - p[:, :, None]) ** 2).sum(-1))            # (T, N, N)
    d[:, np.arange(n), np.arange(n)] = np.nan
    with empty_slices_quiet():
        mean_d = np.nanmean(d, axis=2)                                  # (T, N)
        distance = np.nanmean(mean_d, axis=0)
        spread = np.nanstd(mean_d, axis=0)
        w = max(int(round(pace_window_s / dt)), 1)
        if T < 2 * w:
            w = max(T // 4, 1)
        disp = np.sqrt(((p[w:] - p[:-w]) ** 2).sum(-1)) if T > w else np.full((0, n), np.nan)
        pace = np.nanmean(disp, axis=0) / (w * dt)
        v = np.sqrt((np.diff(p, axis=0) ** 2).sum(-1)) / dt
        mean_speed, std_speed = np.nanmean(v, axis=0), np.nanstd(v, axis=0)
    return {'distance': distance, 'spread': spread, 'pace': pace,
            'mean_speed': mean_speed, 'std_speed': std_speed}


def observed_like(sim: HerdTrajectory, data: np.ndarray, data_times: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(run positions, data positions), both (T', N, 2) over the run's span, the run's
    NaN wherever the data's animal is absent (module docstring: like with like). ``sim``
    covers a tail of ``data_times`` (a free run starts at the data's first complete
    snapshot) on the same clock; ``data`` (T, N, 2) in the run's agent order."""
    data = np.asarray(data, dtype=float)
    k0 = int(np.searchsorted(np.asarray(data_times, dtype=float), float(sim.times[0]) - 1e-9))
    span = data[k0:k0 + sim.n_steps]
    pos = np.asarray(sim.positions, dtype=float)[:len(span)]
    absent = ~np.isfinite(span).all(axis=-1)
    return np.where(absent[..., None], np.nan, pos), span


def free_run_fidelity(model, run: HerdTrajectory, seeds: int = SEEDS) -> dict:
    """The law of ``model`` run freely from the start of ``run`` for its length (``seeds``
    noise seeds, simulated together by :func:`~herd_ros.simulation.herd_simulator.
    simulate_from_each`) against ``run``, each run observed like the data
    (:func:`observed_like`).

    Returns {'steps', 'seeds', 'agents', 'herd': {stat: row}, 'per_agent': {agent: {stat:
    row}}} with row = {'data', 'median', 'min', 'max', 'relative'} (relative = median/data −
    1; the herd's row is over the mean of the animals' values).
    """
    from herd_ros.simulation.herd_simulator import simulate_from_each
    agents = list(model.agents)
    order = [run.agents.index(a) for a in agents]
    positions = run.positions[:, order]
    data = None
    sims = []
    start = HerdTrajectory(run.times, agents, positions)
    for sim in simulate_from_each(model, [start] * seeds, range(seeds)):
        seen, span = observed_like(sim, positions, run.times)
        if data is None:                  # the same span for every seed
            data, steps = shape_and_pace(span, model.dt), len(span)
        sims.append(shape_and_pace(seen, model.dt))

    def row(values_data, values_sims):
        arr = np.asarray(values_sims, dtype=float)
        med = float(np.median(arr)) if np.isfinite(arr).all() else float('nan')
        ref = float(values_data)
        return {'data': ref, 'median': med, 'min': float(np.min(arr)),
                'max': float(np.max(arr)),
                'relative': med / ref - 1.0 if ref and np.isfinite(ref) else float('nan')}

    per_agent = {a: {k: row(data[k][i], [s[k][i] for s in sims]) for k in STATISTICS}
                 for i, a in enumerate(agents)}
    with empty_slices_quiet():
        herd = {k: row(np.nanmean(data[k]), [np.nanmean(s[k]) for s in sims])
                for k in STATISTICS}
    return {'steps': int(steps), 'seeds': int(seeds), 'agents': agents, 'herd': herd,
            'per_agent': per_agent}


def format_free_run(result: dict, per_agent: bool = False) -> str:
    """The free-run table: per statistic the data, the runs' median [min, max] and the
    relative difference (herd, then each animal when ``per_agent``)."""
    lines = [f'free run from the held-out start ({result["steps"]} steps, {result["seeds"]} '
             f'noise seeds; median [min, max] of the runs vs the data):']
    rows = [('herd', result['herd'])]
    if per_agent:
        rows += list(result['per_agent'].items())
    width = max(len(name) for name, _ in rows)
    for name, stats in rows:
        cells = []
        for k in STATISTICS:
            r = stats[k]
            if not np.isfinite(r['data']):
                # distance and spread need two animals at a step: with one, not measured
                cells.append(f'{k.replace("_", " ")} not measured (no data: '
                             + ('fewer than two animals at every step)'
                                if k in ('distance', 'spread') else 'too few steps)'))
                continue
            cells.append(f'{k.replace("_", " ")} {r["median"]:.3g} [{r["min"]:.3g}, '
                         f'{r["max"]:.3g}] vs {r["data"]:.3g} ({100 * r["relative"]:+.0f} %)')
        lines.append(f'  {name:<{width}}  ' + '; '.join(cells))
    return '\n'.join(lines)
