"""`herd-ros report`: figures and summary of a model file against data (no refit)."""
from __future__ import annotations

import json
from pathlib import Path


HELP = 'figures (paper Figs. 2-6) and summary.json of a model file on a data file'


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('model', help='model file')
    p.add_argument('data', help='trajectory CSV, GPS CSV or bag to evaluate on')
    p.add_argument('-o', '--out', required=True, help='report directory')
    p.add_argument('--dt', type=float, help='herd clock step (s) for GPS data')
    p.add_argument('--seed', type=int, default=0, help='seed of the simulation')


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.data_sources import load_runs
    from herd_ros.estimation.validation import skill_lines
    from herd_ros.herd_dynamics import HerdDynamics
    from herd_ros.report.fit_figures import write_fit_figures
    dyn = HerdDynamics.load(args.model)
    runs, _ = load_runs(args.data, dt=args.dt or dyn.model.dt)
    summary = dyn.score(runs, seed=args.seed)
    paths = write_fit_figures(dyn.report_fit(runs), summary, runs, args.out)
    public = {k: v for k, v in summary.items() if not k.startswith('_')}
    public['figures'] = [p.name for p in paths]
    (Path(args.out) / 'summary.json').write_text(json.dumps(public, indent=1))
    print('\n'.join(skill_lines(summary)))
    from herd_ros.simulation.free_run import format_free_run
    print(format_free_run(summary['free_run'], per_agent=True))
    from herd_ros.estimation.shared_residuals import format_shared_residuals
    print(format_shared_residuals(summary['shared_residuals']))
    print(f'report: {len(paths)} figures and summary.json in {args.out}')
    return 0
