"""`herd-ros imitate DATA -o policy.yaml`: learn swarm policies from a trajectory CSV.

The pipeline is :func:`herd_ros.imitation.learning.learn_policy` (Rahman, White et al.,
ACC 2023, with instrumental variables against the position noise). Results: the policy YAML,
and with ``--report DIR`` AMD/AVD plots, trajectory pictures and ``summary.json``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.imitation.policies import ALL_POLICIES

HELP = 'learn swarm imitation policies (gains, radius, v_max) from a trajectory CSV'


def parse_walls(text):
    """The box ``XMIN,XMAX,YMIN,YMAX`` of ``--walls`` as four numbers (None when not given)."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(',')]
    except ValueError:
        raise HerdInputError(f'--walls: {text!r} is not four numbers XMIN,XMAX,YMIN,YMAX') \
            from None
    if len(values) != 4:
        raise HerdInputError(f'--walls: need XMIN,XMAX,YMIN,YMAX (got {text!r})')
    return values


def add_arguments(parser):
    """The verb's options (``herd-ros VERB --help``)."""
    parser.add_argument('data', help='trajectory CSV: time,agent,x,y[,run]')
    parser.add_argument('-o', '--output', required=True, help='policy YAML to write')
    parser.add_argument('--policies', default='cohesion,separation2,alignment',
                        help='comma-separated policy names; all: ' + ','.join(ALL_POLICIES))
    parser.add_argument('--walls', help='enclosure XMIN,XMAX,YMIN,YMAX (m) for wall policies')
    parser.add_argument('--radius', type=float, help='fix the communication radius (m)')
    parser.add_argument('--v-max', type=float, help='fix the speed limit (m/s)')
    parser.add_argument('--prune', type=float, default=None,
                        help='second pass keeping policies with |k| >= PRUNE (paper: 0.1)')
    parser.add_argument('--naive', action='store_true',
                        help='plain least squares (no errors-in-variables correction)')
    parser.add_argument('--report', help='directory for plots and summary.json')


def _write_report(directory: Path, fit, runs, comparison):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    t = comparison['time']
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, key, unit in ((axes[0], 'amd', 'm'), (axes[1], 'avd', 'm/s')):
        ax.plot(t, comparison[f'{key}_data'], label='data')
        ax.plot(t, comparison[f'{key}_imitation'], '--', label='imitation')
        ax.set_xlabel('time (s)')
        ax.set_ylabel(f'{key.upper()} ({unit})')
        ax.legend()
    fig.suptitle('average mean distance / velocity difference, mean over runs')
    fig.tight_layout()
    fig.savefig(directory / 'amd_avd.png', dpi=100)
    plt.close(fig)
    for k, run in enumerate(runs[:3]):
        fig, axes = plt.subplots(1, 2, figsize=(10, 5), sharex=True, sharey=True)
        sim = comparison['positions'][k]
        for ax, pos, title in ((axes[0], run.positions[1:], 'data'),
                               (axes[1], sim, 'imitation')):
            ax.plot(pos[:, :, 0], pos[:, :, 1], lw=0.6)
            ax.plot(pos[0, :, 0], pos[0, :, 1], 'k.', ms=3)
            ax.set_title(f'{title} (run {run.run})')
            ax.set_aspect('equal')
            ax.set_xlabel('x (m)')
        axes[0].set_ylabel('y (m)')
        fig.tight_layout()
        fig.savefig(directory / f'trajectories_{k}.png', dpi=100)
        plt.close(fig)
    p = fit.policy
    summary = {
        'policies': p.policies, 'gains': p.gains.tolist(),
        'gains_se': [None if not np.isfinite(s) else float(s) for s in p.gains_se],
        'radius': p.radius, 'v_max': p.v_max, 'dt': p.dt,
        'v_max_speed_estimate': fit.v_max_estimate.v_max,
        'v_max_method': fit.v_max_estimate.method,
        'mae': fit.mae, 'mae_constant_velocity': fit.mae_constant_velocity,
        'mae_stay_put': fit.mae_stay_put, 'n_samples': fit.n_samples,
        'saturated_share': fit.saturated_share, 'timings_s': fit.timings,
        'amd_max_relative_gap': float(np.max(np.abs(comparison['amd_imitation']
                                                    - comparison['amd_data'])
                                             / comparison['amd_data'])),
        'avd_max_relative_gap': float(np.max(np.abs(comparison['avd_imitation']
                                                    - comparison['avd_data'])
                                             / comparison['avd_data'])),
    }
    (directory / 'summary.json').write_text(json.dumps(summary, indent=2))


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from tqdm import tqdm

    from herd_ros.imitation.learning import learn_policy
    from herd_ros.imitation.metrics import compare_with_imitation
    from herd_ros.imitation.policy_file import write_policy_file
    from herd_ros.trajectory import read_trajectory_csv

    runs = read_trajectory_csv(args.data)
    policies = [p for p in args.policies.split(',') if p.strip()]
    stages = ['radius search', 'gain fit']
    bar = tqdm(total=len(stages) + (1 if args.report else 0), file=sys.stderr,
               desc='imitate', leave=False)

    def progress(stage):
        bar.set_postfix_str(stage)
        bar.update(1 if stage != stages[0] else 0)

    fit = learn_policy(runs, policies, walls=parse_walls(args.walls), radius=args.radius,
                       v_max=args.v_max, errors_in_variables='none' if args.naive else 'iv',
                       prune_below=args.prune, progress=progress)
    bar.update(1)
    write_policy_file(args.output, fit.policy)
    if args.report:
        bar.set_postfix_str('report')
        comparison = compare_with_imitation(fit.policy, runs)
        _write_report(Path(args.report), fit, runs, comparison)
        bar.update(1)
    bar.close()
    print(fit.summary())
    print(f'wrote {args.output}' + (f' and report in {args.report}' if args.report else ''))
    return 0
