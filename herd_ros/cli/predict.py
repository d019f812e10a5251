"""`herd-ros predict`: k-step-ahead positions of every agent, with their covariance.

PRED.csv (doc/formats.md): ``time,agent,x,y,cov_xx,cov_xy,cov_yy[,run]`` — the position
predicted for ``time`` from the data up to ``time − K·dt`` and the covariance of
that prediction (m²): the model's k-step covariance
(:func:`~herd_ros.simulation.prediction.prediction_covariance`) times the agent's running noise
level in the data up to the origin (:func:`~herd_ros.simulation.prediction.noise_level`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from herd_ros.errors import HerdInputError

# the verb's work imports pandas, the model and the data readers where it needs them:
# `herd-ros predict --help` then reads no more than argparse

HELP = 'predict every agent K steps ahead with a model file, with the covariance'


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('model', help='model file written by `herd-ros fit` (any kind)')
    p.add_argument('data', help="trajectory CSV in the model's frame, or GPS data (GPS CSV, "
                                "Movebank, GPX, bag: converted with the model's datum)")
    p.add_argument('-o', '--output', required=True, help='predictions CSV to write')
    p.add_argument('--steps', type=int, default=1, metavar='K',
                   help='predict K model steps ahead (default: 1)')


def _runs_for(model, path):
    """The data's runs on the model's clock and frame, columns in the model's agent order."""
    from herd_ros.data_sources import is_trajectory_csv, load_runs
    path = Path(path)
    if is_trajectory_csv(path):
        runs, _ = load_runs(path)
        if any(abs(r.dt - model.dt) > 1e-6 * model.dt for r in runs):
            runs, _ = load_runs(path, dt=model.dt)   # irregular or another clock: ingest
    else:
        extra = {'datum': model.datum} if model.datum is not None else {}
        runs, _ = load_runs(path, dt=model.dt, **extra)
    out = []
    for r in runs:
        missing = [a for a in model.agents if a not in r.agents]
        if missing:
            raise HerdInputError(f'{path}: no data for agent(s) {", ".join(missing)} of the '
                                 f'model')
        out.append((r, r.positions[:, [r.agents.index(a) for a in model.agents]]))
    return out


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    import pandas as pd

    from herd_ros.herd_dynamics import HerdDynamics
    from herd_ros.model.model_file import write_atomic
    from herd_ros.simulation.prediction import CHI2_2_90
    if args.steps < 1:
        raise HerdInputError(f'--steps must be at least 1, got {args.steps}')
    dyn = HerdDynamics.load(args.model)
    model = dyn.model
    runs = _runs_for(model, args.data)
    frames = []
    hits = total = 0
    sq = 0.0
    naive = {}               # method: [squared error, count] on the samples every one has
    for r, p in runs:
        pred, cov = dyn.predict(p, args.steps, return_cov=True)     # (T, N, 2), (T, N, 2, 2)
        _add_naive(naive, r, p, pred, model.agents, args.steps)
        ok = np.isfinite(pred).all(-1)                               # (T, N)
        tt, ii = np.nonzero(ok)
        c = cov[tt, ii]
        frame = pd.DataFrame({
            'time': r.times[tt], 'agent': np.asarray(model.agents, dtype=object)[ii],
            'x': pred[tt, ii, 0], 'y': pred[tt, ii, 1],
            'cov_xx': c[:, 0, 0], 'cov_xy': c[:, 0, 1], 'cov_yy': c[:, 1, 1]})
        if len(runs) > 1 or r.run is not None:
            frame.insert(0, 'run', r.run if r.run is not None else str(len(frames)))
        frames.append(frame)
        # how many observed positions fall in the 90 % ellipse (a check users want to see)
        seen = ok & np.isfinite(p).all(-1)
        if seen.any():
            tt, ii = np.nonzero(seen)
            e = p[tt, ii] - pred[tt, ii]
            c = cov[tt, ii]
            m2 = np.einsum('mi,mij,mj->m', e, np.linalg.pinv(c), e)
            hits += int((m2 <= CHI2_2_90).sum())
            sq += float((e ** 2).sum())
            total += len(m2)
    if not frames or sum(len(f) for f in frames) == 0:
        raise HerdInputError(f'{args.data}: no step has the {args.steps + 1} earlier steps a '
                             f'prediction needs')
    table = pd.concat(frames)
    write_atomic(args.output, table.to_csv(index=False, float_format='%.6f'))
    print(f'wrote {len(table)} predictions ({model.n_agents} agents, {args.steps} step'
          f'{"s" if args.steps > 1 else ""} of {model.dt:g} s ahead) to {args.output}')
    if total:
        print(f'observed positions: RMS error {np.sqrt(sq / total):.3f} m, inside the 90 % '
              f'prediction ellipse {hits / total:.1%} (of {total})')
    line = naive_line(naive, args.steps)
    if line:
        print(line)
    return 0


def _add_naive(acc: dict, run, p, pred, agents, k: int) -> None:
    """Add the squared errors of the model and the naive predictors (stay-put, constant
    velocity and, for GPS input, the last raw fix) over the positions where all of them
    predict and the position is observed to ``acc`` ({method: [sum, count]})."""
    from herd_ros.simulation.prediction import last_raw_fix_ahead, naive_ahead
    preds = {'model': pred, **naive_ahead(p, k)}
    raw = last_raw_fix_ahead(run, agents, k)
    if raw is not None:
        preds['last_raw_fix'] = raw
    sq = {m: ((x - p) ** 2).sum(-1) for m, x in preds.items()}
    ok = np.logical_and.reduce([np.isfinite(v) for v in sq.values()])
    for m, v in sq.items():
        total = acc.setdefault(m, [0.0, 0])
        total[0] += float(v[ok].sum())
        total[1] += int(ok.sum())


NAIVE_NAMES = {'model': 'model', 'stay_put': 'stay-put', 'constant_velocity':
               'constant velocity', 'last_raw_fix': 'last raw fix (GPS input: the fix '
               'before the origin tick, no filter)'}


def naive_line(acc: dict, k: int) -> str | None:
    """The model's RMS beside the naive predictors', on the same positions."""
    n = acc.get('model', [0.0, 0])[1]
    if not n:
        return None
    cells = ', '.join(f'{NAIVE_NAMES[m]} {np.sqrt(s / c):.3f}' for m, (s, c) in acc.items())
    return (f'{k} step{"s" if k > 1 else ""} ahead, RMS (m) on the {n} positions every '
            f'predictor reaches: {cells}')
