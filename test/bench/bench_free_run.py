"""Free-run fidelity on the shipped real herds (issue 30, acceptance 1's measure): fitted by
`herd-ros fit` on the first half (defaults: --field auto --noise auto; and each field
forced with Gaussian noise), the law run
freely from the second half's start for its length, 5 noise seeds; herd distance, spread
and pace of the runs (median [min, max]) against the second half, beside the one-step RMS.
The bar of the issue: distance and spread within 25 %, pace within 35 %.

    .venv/bin/python test/bench/bench_free_run.py
"""
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HERDS = {'baboons': ROOT / 'bags' / 'baboons_1h', 'steers': ROOT / 'bags' / 'steers_72h.csv'}
VARIANTS = {'defaults': [], 'fitted, gaussian': ['--field', 'fitted', '--noise', 'gaussian'],
            'space-use, gauss.': ['--field', 'space-use', '--noise', 'gaussian']}


def main():
    print(f'{"herd":<8} {"fit":<18} {"one-step":>9} {"distance":>22} {"spread":>22} '
          f'{"pace":>22}')
    with tempfile.TemporaryDirectory() as tmp:
        for herd, data in HERDS.items():
            for name, extra in VARIANTS.items():
                out = Path(tmp) / f'{herd}_{name.replace(" ", "_")}'
                subprocess.run([sys.executable, '-m', 'herd_ros.cli.main', 'fit', str(data),
                                '-o', str(out) + '.yaml', '--train-fraction', '0.5',
                                '--report', str(out), *extra], check=True,
                               capture_output=True, cwd=ROOT)
                summary = json.loads((out / 'summary.json').read_text())
                fr, one = summary['free_run']['herd'], summary['one_step_rms']['model']
                cells = []
                for k in ('distance', 'spread', 'pace'):
                    r = fr[k]
                    lo, hi = 100 * (r['min'] / r['data'] - 1), 100 * (r['max'] / r['data'] - 1)
                    cells.append(f'{100 * r["relative"]:+5.0f} % [{lo:+.0f}, {hi:+.0f}]')
                print(f'{herd:<8} {name:<18} {one["herd"]:>9.3f} ' + ' '.join(
                    f'{c:>22}' for c in cells), flush=True)
    print('relative to the held-out half: median of 5 seeds [min, max]; reproduce: '
          '.venv/bin/python test/bench/bench_free_run.py')


if __name__ == '__main__':
    main()
