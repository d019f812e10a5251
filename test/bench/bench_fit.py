"""Batch fit time of the herd model (issues: offline identification, acceptance 5; model
selection, acceptance 5).

Cases: 3 agents × 3 100 steps, and 10 agents × 259 200 steps (3 days at 1 Hz). Data: a
known-truth herd (herd_ros.synthesis.known_truth). Times, beside each other:
* the single fit of the paper's full model on an 8x8 grid (regressors, structured QR,
  sandwich errors);
* the selected fit as `herd-ros fit` does it by default: blocked cross-validation of every
  candidate (model_selection.select_model), then the final fit of the chosen structure;
* the whole default fit, ``HerdDynamics().fit`` (what `herd-ros fit` runs: the selected fit
  plus the long-run terms: the field, herd-place and noise checks on a validation tail and the
  free-run noise calibration), once per case.
Not the simulation of the data. Prints medians over repeats.

    .venv/bin/python test/bench/bench_fit.py
"""
import statistics
import time

from herd_ros.estimation.herd_fit import fit_herd, fit_structure
from herd_ros.herd_dynamics import HerdDynamics
from herd_ros.estimation.model_selection import select_model
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model

CASES = [(3, 3100, 7), (10, 259_200, 3)]


def _selected_fit(run):
    sel = select_model([run.positions], list(run.agents), run.dt)
    fit_structure([run], sel.chosen, law=sel.law, profile=sel.profile, bounds=sel.bounds)
    return sel


def main():
    print(f'{"agents":>6} {"steps":>8} {"params/agent":>12} {"median fit (s)":>15} '
          f'{"min (s)":>8} {"median selected fit (s)":>24} {"candidates":>10} {"repeats":>7}')
    for n, steps, repeats in CASES:
        truth = make_truth_model(n, seed=0, grid=(8, 8), bounds=(-75, 75, -75, 75))
        run = simulate(truth, steps, initial_positions(truth, seed=0, spread=25), seed=1)
        times, selected = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fit = fit_herd([run], grid=(8, 8), bounds=(-75, 75, -75, 75))
            times.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            sel = _selected_fit(run)
            selected.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        whole = HerdDynamics().fit(run)
        whole_s = time.perf_counter() - t0
        p = len(fit.model.laws[truth.agents[0]].theta)
        print(f'{n:>6} {steps:>8} {p:>12} {statistics.median(times):>15.3f} '
              f'{min(times):>8.3f} {statistics.median(selected):>24.3f} {len(sel.table):>10} '
              f'{repeats:>7}   chosen: {sel.chosen.label()}; whole default fit {whole_s:.1f} s '
              f'(field {whole.choices.get("field")}, noise scale '
              f'{whole.choices.get("noise_scale", {}).get("iterations", "-")} iterations)',
              flush=True)
    print('reproduce: make bench  (or .venv/bin/python test/bench/bench_fit.py)')


if __name__ == '__main__':
    main()
