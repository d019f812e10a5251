"""`herd-ros fit`: batch least squares of the herd model (Schwager et al. 2007) on a data file."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from herd_ros.cli.common import parse_floats, parse_grid, progress
from herd_ros.cli.ingest import add_filter_arguments, filter_kwargs
from herd_ros.errors import HerdInputError
from herd_ros.fit_defaults import (DEFAULT_MIN_VISITS, FIELD_CELLS, FOLDS, MEMORIES,
                                   PAIRWISE_MAX_AGENTS, RIDGES, TERMS)

# the fit, the model and the data readers are imported where they are used: `herd-ros fit
# --help` then reads no more than argparse and numpy

HELP = 'fit the herd model to a trajectory CSV, GPS CSV or bag; write the model file'


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('data', help='trajectory CSV (time,agent,x,y[,run]), GPS CSV, GPX or bag')
    p.add_argument('-o', '--output', required=True, help='model file to write (ROS params YAML)')
    p.add_argument('--terms', default='auto', choices=('auto',) + TERMS + ('full',),
                   help='model terms; auto = chosen by blocked cross-validation of the '
                        'one-step error (full = damping+interactions+field, the paper)')
    p.add_argument('--grid', default='auto',
                   help='RBF field grid NXxNY; auto = chosen by cross-validation among '
                        '%s cells over the visited region' % '/'.join(map(str, FIELD_CELLS)))
    p.add_argument('--bounds', help='grid bounds XMIN,XMAX,YMIN,YMAX in metres '
                                    '(default: the visited region)')
    p.add_argument('--min-visits', type=int, default=DEFAULT_MIN_VISITS,
                   help='samples of an agent a grid cell needs to keep its centre')
    p.add_argument('--ridge', default='auto',
                   help='ridge λ on column-scaled parameters (0 = plain least squares); '
                        'auto = chosen by cross-validation among %s'
                        % ', '.join(f'{r:g}' for r in RIDGES))
    p.add_argument('--velocity-memory', metavar='KAPPA', default='auto',
                   help='κ in (0, 1]: the damping acts on the exponentially weighted velocity '
                        'ū ← (1−κ)ū + κu (1 = the paper\'s last velocity); auto = 1, or one of '
                        '%s if cross-validation keeps it' % ', '.join(f'{k:g}' for k in MEMORIES))
    p.add_argument('--loss', choices=('l2', 'robust'), default='l2',
                   help='l2: least squares; robust: outlier-robust IRLS (Mahalanobis-weighted, '
                        'bounded influence), for data with bursts of bad positions')
    p.add_argument('--folds', type=int, default=FOLDS,
                   help='contiguous blocks per run for the cross-validation')
    p.add_argument('--train-fraction', default='auto',
                   help='first fraction of every run used for fitting, the rest held out; '
                        'auto = 0.8, or, if an animal would then have no held-out data (its '
                        'collar ended before the split), the largest fraction at which every '
                        'animal holds out 20 %% of its own positions')
    p.add_argument('--se', choices=('sandwich', 'ols'), default='sandwich',
                   help='standard errors: cluster-robust sandwich or textbook OLS')
    p.add_argument('--dt', type=float, help='herd clock step (s) for GPS data')
    p.add_argument('--smoother', choices=('none', 'rts', 'lag', 'fir'), default='none',
                   help='offline smoothing of GPS data')
    add_filter_arguments(p)
    p.set_defaults(motion_model='fixed')      # the law is learned from the fixed-model track
    p.add_argument('--report', metavar='DIR', help='write figures and summary.json here')
    p.add_argument('--field', choices=('auto', 'fitted', 'space-use'), default='auto',
                   help='environment field: fitted = least squares with the rest of the law '
                        '(kept only if cross-validation does); space-use = the Langevin field '
                        'that makes each agent spend its time where the animal did (for '
                        'simulations and robots that must stay in the range over hours); '
                        'auto = space-use when, on a validation tail of the training data, '
                        'it makes the law run freely closer to the herd (distance, spread, '
                        'pace) at most 2 %% worse one step ahead, else fitted')
    p.add_argument('--herd-place', choices=('auto', 'on', 'off'), default='auto',
                   help='each agent\'s place in the herd: a pull at the edge of the range of '
                        'its offset from the others\' centroid (what holds a herd together in '
                        'a free run when its law alone lets it drift apart); auto = on when, '
                        'on a validation tail of the training data, the law runs more than '
                        '10 %% off without it and it makes the law run freely closer to '
                        'the herd (its error at most 0.8 times) at most 2 %% worse one step '
                        'ahead, else off')
    p.add_argument('--noise', choices=('auto', 'gaussian', 'regimes'), default='auto',
                   help='noise of the law: gaussian = N(0, Q_i) (the paper); regimes = '
                        'stop-and-go, 1-3 noise levels switching as a Markov chain, chosen by '
                        'BIC (for animals that rest and move in bursts); auto = regimes when, '
                        'on a validation tail of the training data, they make the law run '
                        'freely clearly closer to the herd (every statistic), else gaussian')
    p.add_argument('--noise-scale', default='auto', metavar='auto|S',
                   help='factor on each animal\'s noise std in free simulation (robots, '
                        'simulate): auto = calibrated per animal so that the law run freely '
                        'keeps the animal\'s 10-minute pace on the training data (the track\'s '
                        'residuals carry the collar\'s error, which a free run would '
                        'integrate); a number = that factor for every animal (1 = the '
                        'residuals\' noise, the paper\'s); predictions keep the residuals\' '
                        'noise')
    p.add_argument('--alignment', choices=('auto', 'off', 'on'), default='auto',
                   help='velocity alignment: each agent matches its neighbours\' velocity '
                        'with a learned distance kernel; auto = tried on the chosen '
                        'structure and kept only if cross-validation does; on = the '
                        'structure chosen among the candidates with alignment')
    p.add_argument('--alignment-neighbourhood', choices=('radius', 'nearest'),
                   default='radius',
                   help='the neighbours an agent aligns with: every one within the radius '
                        '(4 x the typical spacing), or the K nearest within it')
    p.add_argument('--alignment-nearest', type=int, default=7, metavar='K',
                   help='K of --alignment-neighbourhood nearest')
    p.add_argument('--seed', type=int, default=0, help='seed of the validation simulation')
    p.add_argument('--online', action='store_true',
                   help='recursive least squares over the whole file (the estimator node\'s '
                        'method); also writes parameters over time to MODEL.params.csv')
    p.add_argument('--forgetting', type=float, default=1.0,
                   help='RLS forgetting factor λ in (0, 1] (with --online)')
    p.add_argument('--law', choices=('auto', 'pairwise', 'shared'), default='auto',
                   help='interaction law: pairwise (the paper) or shared; auto = pairwise '
                        'up to %d agents, shared above (with --online: pairwise)'
                        % PAIRWISE_MAX_AGENTS)
    p.add_argument('--interact-with-own-profile', metavar='AGENT[,AGENT..]', default='',
                   help='distinguished agents (a dog, a robot, a leader) whose pull on every '
                        'other agent gets its own distance profile instead of being pooled '
                        'into the shared law (implies the shared law); none = never; '
                        'default: with the shared law the selection screens for one such '
                        'agent and keeps it only if cross-validation does')


def _fmt(x, nd=3):
    return 'n/a' if x is None or not np.isfinite(x) else f'{x:.{nd}f}'


def _share(x):
    return 'n/a' if x is None or not np.isfinite(x) else f'{x:.0%}'


def _candidates(args):
    """(terms, grids, ridges) to cross-validate from the options (``None`` = all)."""
    terms = None if args.terms == 'auto' else \
        ['damping+interactions+field' if args.terms == 'full' else args.terms]
    grids = None if args.grid == 'auto' else [parse_grid(args.grid)]
    if args.ridge == 'auto':
        ridges = RIDGES
    else:
        try:
            ridges = (float(args.ridge),)
        except ValueError:
            raise HerdInputError(f'--ridge takes a number ≥ 0 or auto, got {args.ridge!r}') \
                from None
        if not (np.isfinite(ridges[0]) and ridges[0] >= 0):
            raise HerdInputError(f'--ridge must be a finite number ≥ 0, got {args.ridge}')
    if args.folds < 2:
        raise HerdInputError(f'--folds must be at least 2, got {args.folds}')
    return terms, grids, ridges


def _memories(args) -> tuple[float, tuple]:
    """(κ of every candidate, other κ tried) from ``--velocity-memory``."""
    if args.velocity_memory == 'auto':
        return 1.0, MEMORIES
    from herd_ros.model.velocity_memory import check_memory
    try:
        return check_memory(args.velocity_memory), ()
    except HerdInputError as err:
        raise HerdInputError(f'--velocity-memory takes auto or a number: {err}') from None


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.data_sources import load_runs
    from herd_ros.estimation.herd_fit import choose_train_fraction, split_runs
    from herd_ros.estimation.validation import skill_lines
    from herd_ros.herd_dynamics import FitOptions, HerdDynamics

    # '' = auto (the selection may nominate a driver); 'none' = no own profile
    own_agents = [a.strip() for a in args.interact_with_own_profile.split(',') if a.strip()]
    if own_agents == ['none']:
        own_agents = []
    elif not own_agents:
        own_agents = None
    if own_agents and args.online:
        raise HerdInputError('--interact-with-own-profile is for the batch fit; the online '
                             'estimator has no own profiles')
    if own_agents and args.law == 'pairwise':
        raise HerdInputError('--interact-with-own-profile needs the shared law (the pairwise '
                             'law already gives every pair its own parameters)')
    memory, memories = _memories(args)
    if args.online and (args.field == 'space-use' or args.noise == 'regimes'
                        or args.herd_place == 'on'):
        raise HerdInputError('--field space-use, --herd-place on and --noise regimes are for '
                             'the batch fit (the online estimator keeps its own herd places)')
    if args.online and args.velocity_memory != 'auto':
        raise HerdInputError('--velocity-memory is for the batch fit; the online estimator '
                             'damps the last velocity (κ = 1)')
    if args.online:
        from herd_ros.cli.fit_online import run_online
        if args.law == 'auto':
            args.law = 'pairwise'
        if args.grid == 'auto':
            args.grid = '8x8'
        return run_online(args)
    terms, grids, ridges = _candidates(args)
    bounds = parse_floats(args.bounds, 4, '--bounds') if args.bounds else None
    runs, datum = load_runs(args.data, dt=args.dt, smoother=args.smoother,
                           **filter_kwargs(args))
    from herd_ros.model.model_file import check_agent_id
    for agent in runs[0].agents:          # the model file needs them: say so before the fit
        check_agent_id(agent)
    fraction, note = choose_train_fraction(runs, args.train_fraction)
    if note:
        print(f'note: {note}', flush=True)
    train, test = split_runs(runs, fraction)
    options = FitOptions(terms=terms, grids=grids, bounds=bounds, ridges=ridges, memory=memory,
                         memories=memories, law=None if args.law == 'auto' else args.law,
                         own_agents=own_agents, field=args.field, noise=args.noise,
                         robust=args.loss == 'robust', se=args.se, folds=args.folds,
                         min_visits=args.min_visits, noise_scale=args.noise_scale,
                         place=args.herd_place,
                         alignment=args.alignment,
                         alignment_neighbourhood=args.alignment_neighbourhood,
                         alignment_nearest=args.alignment_nearest)
    dyn = HerdDynamics(options=options).fit(train, datum=datum, seed=args.seed,
                                            progress=progress,
                                            log=lambda line: print(line, flush=True))
    dyn.save(args.output)
    fit, selection = dyn.fit_result, dyn.selection
    summary = dyn.score(test, train=train, seed=args.seed)
    summary['selection'] = dyn.choices
    _print_selection(selection, train[0].dt)
    print('\n'.join(skill_lines(summary)))
    _print_summary(fit, summary, args)
    _print_alignment(fit.model)
    for agent, entry in summary['agents'].items():
        if entry.get('constrained'):
            print(f'stability: {agent}: {entry["constrained"]}')
    from herd_ros.simulation.free_run import format_free_run
    print(format_free_run(summary['free_run'], per_agent=bool(args.report)))
    from herd_ros.estimation.shared_residuals import format_shared_residuals
    print(format_shared_residuals(summary['shared_residuals']))
    if args.report:
        from herd_ros.report.fit_figures import write_fit_figures
        paths = write_fit_figures(fit, summary, train, args.report)
        public = {k: v for k, v in summary.items() if not k.startswith('_')}
        public['model_file'] = str(Path(args.output))
        public['figures'] = [p.name for p in paths]
        public['notes'] = ('The pairwise interaction parameters theta1/theta2 are weakly '
                           'identifiable from realistic data: read them with their 95 % '
                           'intervals (interaction.*.theta*_ci95), not as bare numbers.')
        (Path(args.report) / 'summary.json').write_text(json.dumps(public, indent=1))
        print(f'report: {len(paths)} figures and summary.json in {args.report}')
    return 0


def _print_statistics(statistics: dict, agents) -> None:
    """The law simulated freely over the training span against the training data (herd
    means of the per-agent statistics, Schwager et al. 2007 Fig. 6)."""
    from herd_ros.simulation.statistics import STATISTICS
    real, sim = statistics['real'], statistics['simulated']
    cells = []
    for k in STATISTICS:
        want = float(np.nanmean([real[a][k] for a in agents]))
        got = float(np.nanmean([sim[a][k] for a in agents]))
        rel = 100.0 * (got / want - 1.0) if want else float('nan')
        cells.append(f'{k.replace("_", " ")} {got:.3g} vs {want:.3g} ({rel:+.0f} %)')
    print('simulated herd vs training data (herd means; the law run freely from the first '
          'step):\n  ' + '; '.join(cells))


def _print_alignment(model) -> None:
    """The fitted alignment kernel of the herd (mean weights) at its bumps, with the
    standard error of the mean."""
    if model.alignment is None:
        return
    s = model.alignment.summary(model.agents)
    cells = ', '.join(f'{c:.0f} m: {w:+.3f}' + (f' ± {e:.3f}' if np.isfinite(e) else '')
                      for c, w, e in zip(s['bump_centres_m'], s['herd_weights'],
                                         s['herd_weights_se']))
    print(f'alignment ({s["kernel"]}): herd kernel weights at the bumps {cells}')


def _print_selection(selection, dt, rows: int = 8):
    """The cross-validation table: the best candidates, the chosen one and the baselines."""
    table = sorted(selection.table, key=lambda r: r['mse'])
    shown = table[:rows]
    chosen = next(r for r in table if r['structure'] == selection.chosen)
    if chosen not in shown:
        shown.append(chosen)
    law = f', interactions: {selection.law} law' if any(
        r['structure'].interactions for r in table) else ''
    outside = (f'; {selection.outside_region} held-out samples outside the region the other '
               f'blocks cover not scored' if selection.outside_region else '')
    print(f'model selection: blocked cross-validation on the training data ({selection.folds} '
          f'blocks per run, {selection.samples} samples{law}{outside}); one-step RMS (m)')
    print(f'  {"candidate":<44} {"params/agent":>12} {"CV RMS":>9}')
    for r in shown:
        mark = '  <- chosen (simplest within 1 SE of the best)' \
            if r['structure'] == selection.chosen else ''
        print(f'  {r["structure"].label():<44} {r["n_params"]:>12g} {r["rms"]:9.4f}{mark}')
    for name, v in selection.baselines.items():
        print(f'  {name.replace("_", " "):<44} {"":>12} {v:9.4f}')
    if len(table) > len(shown):
        print(f'  ({len(table) - len(shown)} more candidates in the report)')


def _print_summary(fit, summary, args):
    ev = summary['evaluated_on']
    one = summary['one_step_rms']
    print(f'model: {args.output}  ({fit.model.n_agents} agents, dt {fit.model.dt:g} s, '
          f'{summary["agents"][fit.model.agents[0]]["samples"]} training samples per agent)')
    raw = one.get('last_raw_fix')
    print(f'one-step RMS (m) on {ev} data: model / constant velocity / stay-put / damping '
          f'only' + (' / last raw fix (GPS input: the fix before the tick, no filter)'
                     if raw else '') + '; whiteness = fraction of lags inside the 90 % '
          'band, Ljung-Box Q')
    print(f'{"agent":>12} {"damping":>16} {"model":>8} {"const-v":>8} {"stay":>8} '
          f'{"damp":>8} ' + (f'{"raw fix":>8} ' if raw else '')
          + f'{"white v":>8} {"white w":>8} {"LB v":>10} {"LB w":>10}')
    for a in fit.model.agents:
        s = summary['agents'][a]
        wv, wr = s['whiteness_velocity'], s['whiteness_residual']
        print(f'{a:>12} {s["damping"]:8.4f}±{_fmt(s["damping_se"], 4):<7} '
              f'{_fmt(one["model"][a]):>8} {_fmt(one["constant_velocity"][a]):>8} '
              f'{_fmt(one["stay_put"][a]):>8} {_fmt(one["damping_only"][a]):>8} '
              + (f'{_fmt(raw[a]):>8} ' if raw else '')
              + f'{_share(wv["inside_90"]):>8} {_share(wr["inside_90"]):>8} '
              f'{_fmt(wv["ljung_box"], 1):>10} {_fmt(wr["ljung_box"], 1):>10}')
    print(f'{"herd":>12} {"":16} {one["model"]["herd"]:8.3f} '
          f'{one["constant_velocity"]["herd"]:8.3f} {one["stay_put"]["herd"]:8.3f} '
          f'{one["damping_only"]["herd"]:8.3f}' + (f' {raw["herd"]:8.3f}' if raw else ''))
    _print_statistics(summary['statistics'], fit.model.agents)
    weak = [k for k, c in summary['interaction'].items() if not c['identifiable']]
    if weak:
        print(f'note: {len(weak)} of {len(summary["interaction"])} pairwise interactions are '
              f'not significantly identified (95 % interval of theta1 or theta2 includes 0); '
              f'see the report')
