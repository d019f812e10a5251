"""The herding benchmark of issue 27: Strömbom's shepherd against the model herder
(receding horizon over the learned response to the dog, refitted online in every episode),
paired episodes per setting:
success rate (Wilson 95 % interval), median time, spread, path.

Settings (N animals, herders, noise e, cohesion n, the animals' law): N = 14 at e = 0.3,
0.6 and 1.0, with 1 and 3 herders, Strömbom's sheep and the herd-law family (which the model
herder, fitted on Strömbom's sheep, was not told); cohesion n = N/2, 6, 5 and 3
(short-range; 50 episodes: a failing episode runs its whole budget); N = 46 at e = 0.3;
N = 100 with 3 herders (20 episodes: the planner forms every pair of 100
animals for 13 candidates × 25 steps, ~17 s of planning per episode).

    .venv/bin/python test/bench/bench_herding.py [--seeds 200]
"""
import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from herd_ros.cli.herding import model_herder  # noqa: E402
from herd_ros.herding.benchmark import (Setting, run_episodes, strombom_herder,  # noqa: E402
                                        summarise)

SETTINGS = ((Setting(14, 1, 0.3), 1.0), (Setting(14, 1, 0.6), 1.0), (Setting(14, 1, 1.0), 1.0),
            (Setting(14, 3, 0.3), 1.0), (Setting(14, 1, 0.3, family='herd-law'), 1.0),
            (Setting(14, 1, 0.3, 6), 1.0), (Setting(14, 1, 0.3, 5), 1.0),
            (Setting(14, 1, 0.3, 3), 0.25), (Setting(46, 1, 0.3), 1.0),
            (Setting(100, 3, 0.3), 0.1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seeds', type=int, default=200)
    args = ap.parse_args()
    print(f'{"setting":<36} {"herder":<9} {"episodes":>8} {"success":>8} {"95 % interval":>16} '
          f'{"median time":>12} {"spread":>7} {"path":>7} {"wall":>7}')
    for st, share in SETTINGS:
        seeds = range(max(10, int(args.seeds * share)))
        for name in ('strombom', 'model'):
            t0 = time.perf_counter()
            policy = strombom_herder if name == 'strombom' else model_herder(st)
            row = summarise(run_episodes(st, policy, seeds), st)
            t = f'{row["median_time_s"]:.0f} s' if row['median_time_s'] is not None else '-'
            print(f'{st.label():<36} {name:<9} {len(seeds):8d} {row["success"]:8.1%} '
                  f'[{row["ci"][0]:5.1%}, {row["ci"][1]:5.1%}] {t:>12} '
                  f'{row["mean_spread_m"]:5.1f} m {row["herder_path_m"]:5.0f} m '
                  f'{time.perf_counter() - t0:6.1f} s', flush=True)
    print(f'reproduce: .venv/bin/python test/bench/bench_herding.py --seeds {args.seeds}')


if __name__ == '__main__':
    main()
