"""`herd-ros report`: figures and summary of a model file against data (no refit)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from herd_ros.data_sources import load_runs
from herd_ros.estimation.herd_fit import HerdFit
from herd_ros.estimation.validation import skill_lines, validate
from herd_ros.model import kinds
from herd_ros.model.rbf_field import FieldGrid

HELP = 'figures (paper Figs. 2-6) and summary.json of a model file on a data file'


def add_arguments(p):
    p.add_argument('model', help='model file')
    p.add_argument('data', help='trajectory CSV, GPS CSV or bag to evaluate on')
    p.add_argument('--out', required=True, help='report directory')
    p.add_argument('--dt', type=float, help='herd clock step (s) for GPS data')
    p.add_argument('--seed', type=int, default=0, help='seed of the simulation')


def run(args) -> int:
    from herd_ros.report.fit_figures import write_fit_figures
    model = kinds.load(args.model)
    runs, _ = load_runs(args.data, dt=args.dt or model.dt)
    pts = np.concatenate([r.positions.reshape(-1, 2) for r in runs])
    grid = FieldGrid.over(pts[np.isfinite(pts).all(-1)], 8, 8)
    fit = HerdFit(model=model, fits={}, grid=grid)
    summary = validate(fit, runs, runs, seed=args.seed)
    paths = write_fit_figures(fit, summary, runs, args.out)
    public = {k: v for k, v in summary.items() if not k.startswith('_')}
    public['figures'] = [p.name for p in paths]
    (Path(args.out) / 'summary.json').write_text(json.dumps(public, indent=1))
    print('\n'.join(skill_lines(summary)))
    from herd_ros.simulation.free_run import format_free_run
    print(format_free_run(summary['free_run'], per_agent=True))
    print(f'report: {len(paths)} figures and summary.json in {args.out}')
    return 0
