"""The herding benchmark of issue 27 with Strömbom's shepherd: success rate (Wilson 95 %
interval), median time, spread and path over 200 paired episodes per setting.

Settings: N = 14 and 46 animals, one herder, noise e = 0.3, cohesion n = N/2 (the paper's
cohesive flock) and n = 3 (short-range); N = 14 also at e = 1.0 and with 3 herders.
(N = 100 costs about 20 minutes per setting on 2 cores with the dense neighbour search:
run it with ``herd-ros herding --animals 100 --herders 1,3``.)

    .venv/bin/python test/bench/bench_herding.py [--seeds 200]
"""
import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from herd_ros.herding.benchmark import (Setting, run_episodes, strombom_herder,  # noqa: E402
                                        summarise)

SETTINGS = (Setting(14, 1, 0.3), Setting(14, 1, 0.3, 3), Setting(14, 1, 1.0),
            Setting(14, 3, 0.3), Setting(14, 3, 0.3, 3), Setting(46, 1, 0.3),
            Setting(46, 1, 0.3, 3))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seeds', type=int, default=200)
    args = ap.parse_args()
    print(f'Strömbom\'s shepherd, {args.seeds} paired episodes per setting')
    print(f'{"setting":<34} {"success":>8} {"95 % interval":>16} {"median time":>12} '
          f'{"spread":>7} {"path":>7} {"wall":>7}')
    for st in SETTINGS:
        t0 = time.perf_counter()
        row = summarise(run_episodes(st, strombom_herder, range(args.seeds)), st)
        t = f'{row["median_time_s"]:.0f} s' if row['median_time_s'] is not None else '-'
        print(f'{st.label():<34} {row["success"]:8.1%} [{row["ci"][0]:5.1%}, {row["ci"][1]:5.1%}]'
              f' {t:>12} {row["mean_spread_m"]:5.1f} m {row["herder_path_m"]:5.0f} m '
              f'{time.perf_counter() - t0:6.1f} s', flush=True)
    print(f'reproduce: .venv/bin/python test/bench/bench_herding.py --seeds {args.seeds}')


if __name__ == '__main__':
    main()
