"""`herd-ros fit --online`: the estimator node's recursive least squares, run over a data file.

Writes the model file (``schwager2007`` or ``schwager2007_shared``) exactly as the node's
``~/save_model`` does, and the parameters over time as a CSV: ``MODEL.params.csv`` next to
the model, or ``DIR/params.csv`` with ``--report DIR``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from herd_ros.cli.common import parse_floats, parse_grid, progress
from herd_ros.data_sources import load_runs
from herd_ros.errors import HerdInputError
from herd_ros.estimation.online_fit import online_fit, write_params_csv


def run_online(args) -> int:
    """``herd-ros fit --online``: the recursive least squares over the data, the model file and
    the parameters over time."""
    grid = parse_grid(args.grid)
    bounds = parse_floats(args.bounds, 4, '--bounds') if args.bounds else None
    if not 0 < args.forgetting <= 1:
        raise HerdInputError(f'--forgetting must be in (0, 1], got {args.forgetting}')
    runs, datum = load_runs(args.data, dt=args.dt, smoother=args.smoother)
    bar = progress(total=sum(r.n_steps for r in runs), desc='recursive least squares',
                   unit='step')
    extra = {}
    if getattr(args, 'alignment', 'off') == 'on':     # the selection's default kernel
        from herd_ros.estimation.herd_fit import aligned_positions
        from herd_ros.estimation.model_selection import default_alignment
        k = default_alignment([aligned_positions(r, list(runs[0].agents)) for r in runs])
        extra = dict(alignment=True, alignment_radius=k.profile.radius,
                     alignment_size=k.size, alignment_neighbourhood=args.alignment_neighbourhood,
                     alignment_nearest=args.alignment_nearest)
    result = online_fit(runs, law=args.law, grid=grid, bounds=bounds,
                        forgetting=args.forgetting, min_visits=args.min_visits,
                        progress=bar.update, robust=getattr(args, 'loss', 'l2') == 'robust',
                        **extra)
    bar.close()
    est = result.estimator
    est.save_model(args.output, datum=datum)
    csv = (Path(args.report) / 'params.csv' if args.report
           else Path(str(args.output) + '.params.csv'))
    write_params_csv(result, csv)
    diag = est.diagnostics()
    se = est.rls.theta_se()
    print(f'model: {args.output}  ({len(est.agents)} agents, {args.law} law, dt {est.dt:g} s, '
          f'forgetting {args.forgetting:g}, {est.rls.n_params} parameters per agent)')
    print(f'parameters over time: {csv}')
    print(f'{"agent":>12} {"samples":>8} {"damping":>16} {"resid RMS":>10} {"lag-1 r":>8}')
    for i, a in enumerate(est.agents):
        print(f'{a:>12} {int(diag["samples"][i]):8d} {est.theta[i, 0]:8.4f}±{se[i, 0]:<7.4f} '
              f'{diag["residual_rms"][i]:10.4f} {diag["lag1_autocorrelation"][i]:8.3f}')
    if not np.isfinite(est.theta).all():
        raise HerdInputError('the recursive estimate is not finite; check the data')
    return 0
