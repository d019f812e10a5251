"""`herd-ros herding`: the herding benchmark (issue 27) — herders drive simulated herds into
a goal circle (:mod:`herd_ros.herding.benchmark`).

Writes to ``--out``: ``summary.json`` (per setting and herder: ``success``, its Wilson 95 %
interval ``ci``, ``median_time_s``, mean and max spread, herder path length, seeds),
``success.png`` (success rates with their intervals) and ``episode.gif`` (one episode of
the first setting, every herder side by side).
"""
from __future__ import annotations

import json
from pathlib import Path

from herd_ros.errors import HerdInputError

HELP = ('herding benchmark: herders (Strömbom\'s shepherd, ...) drive simulated herds into a '
        'goal; success rates with Wilson intervals, figure and GIF')
HERDERS = ('strombom', 'model', 'model-offline')


def _values(text: str, option: str, kind=int) -> list:
    """Comma-separated integers ≥ 1 (``kind`` int) or numbers ≥ 0 (float); one clear error."""
    what, least = ('integers', 1) if kind is int else ('numbers', 0)
    try:
        values = [kind(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise HerdInputError(f'{option} takes comma-separated {what}, got {text!r}') from None
    if not values or min(values) < least:
        raise HerdInputError(f'{option} needs {what} ≥ {least}, got {text!r}')
    return values


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('-o', '--out', type=Path, required=True, help='output directory')
    p.add_argument('--animals', default='14', help='herd sizes N, comma-separated')
    p.add_argument('--herders', default='1', help='numbers of herders, comma-separated')
    p.add_argument('--noise', default='0.3', help='animal noise e, comma-separated')
    p.add_argument('--neighbours', default='half',
                   help='cohesion: the n nearest neighbours each animal is drawn to, '
                        'comma-separated; "half" = half the herd (the paper\'s cohesive flock)')
    p.add_argument('--family', default='strombom',
                   help='the animals\' law, comma-separated: strombom (Strömbom\'s sheep) or '
                        'herd-law (the shared herd law with a driver profile; the model '
                        'herder is always fitted on Strömbom\'s sheep, so this is a law it '
                        'was not told)')
    p.add_argument('--seeds', type=int, default=200,
                   help='episodes per setting (seeds 0..S-1, the same for every herder)')
    p.add_argument('--herder', default='strombom',
                   help='herders to compare, comma-separated, of: strombom (Strömbom et al. '
                        '2014\'s shepherd), model (receding-horizon control over the '
                        'learned response to the dog, refitted online while it herds), '
                        'model-offline (the same without the online refit)')
    p.add_argument('--no-gif', action='store_true', help='skip episode.gif')


def settings_of(args):
    """The benchmark settings of the parsed lists of animals, herders, noises, cohesions and
    families."""
    from herd_ros.herding.benchmark import Setting
    out = []
    from herd_ros.herding.benchmark import FAMILIES
    cohesion = [None if c.strip() == 'half' else c for c in args.neighbours.split(',')]
    families = [f.strip() for f in args.family.split(',') if f.strip()]
    if not families or any(f not in FAMILIES for f in families):
        raise HerdInputError(f'--family takes {", ".join(FAMILIES)}, got {args.family!r}')
    for family in families:
        for n in _values(args.animals, '--animals'):
            for d in _values(args.herders, '--herders'):
                for e in _values(args.noise, '--noise', float):
                    for c in cohesion:
                        k = None if c is None else _values(c, '--neighbours')[0]
                        out.append(Setting(n, d, e, k, family))
    return out


def model_herder(setting, adapt: bool = True):
    """The model herder of a setting: its response learned from recorded episodes of
    Strömbom's sheep with the setting's size, herders, noise and cohesion; refitted online
    in every episode unless ``adapt`` is False (``--herder model-offline``)."""
    from herd_ros.herding.benchmark import Setting
    from herd_ros.herding.model_herder import ModelHerder, learn_response, record_episodes
    learn_on = Setting(setting.n_animals, setting.n_herders, setting.noise,
                       setting.n_neighbours)
    return ModelHerder(learn_response(record_episodes(learn_on)), adapt=adapt)


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.cli.common import progress
    from herd_ros.herding.benchmark import run_episodes, strombom_herder, summarise
    herders = [h.strip() for h in args.herder.split(',') if h.strip()]
    unknown = [h for h in herders if h not in HERDERS]
    if unknown or not herders:
        raise HerdInputError(f'--herder takes {", ".join(HERDERS)}, got {args.herder!r}')
    if args.seeds < 1:
        raise HerdInputError(f'--seeds must be at least 1, got {args.seeds}')
    settings = settings_of(args)
    args.out.mkdir(parents=True, exist_ok=True)
    rows, shown = [], {}
    for st in settings:
        for name in herders:
            policy = (strombom_herder if name == 'strombom' else
                      model_herder(st, adapt=name == 'model'))
            bar = progress(total=st.budget, desc=f'{name} {st.label()}', unit='step')
            result = run_episodes(st, policy, range(args.seeds),
                                  record=0 if not shown.get(name) else None,
                                  progress=bar.update)
            bar.close()
            if result['trajectory'] is not None:
                shown[name] = (st, result['trajectory'])
            row = summarise(result, st) | {'herder': name}
            rows.append(row)
            t = (f'{row["median_time_s"]:.0f} s' if row['median_time_s'] is not None
                 else '-')
            print(f'{st.label():<34} {name:<13} success {row["success"]:6.1%} '
                  f'[{row["ci"][0]:.1%}, {row["ci"][1]:.1%}]  median time {t:>7}  '
                  f'spread {row["mean_spread_m"]:5.1f} m  path {row["herder_path_m"]:6.0f} m',
                  flush=True)
    (args.out / 'summary.json').write_text(json.dumps({'runs': rows}, indent=1))
    from herd_ros.report.herding_figures import episode_gif, success_figure
    success_figure(rows, args.out / 'success.png')
    written = ['summary.json', 'success.png']
    if not args.no_gif and shown:
        episode_gif(shown, args.out / 'episode.gif')
        written.append('episode.gif')
    print(f'wrote {", ".join(written)} to {args.out}')
    return 0
