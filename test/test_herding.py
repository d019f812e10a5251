"""Herding (issue 27): Strömbom's sheep and shepherd by hand, the Wilson interval, the
paper's regime on one setting, and `herd-ros herding`."""
import json
import math

import numpy as np
import pytest

from herd_ros.cli.main import main
from herd_ros.herding.benchmark import (Setting, run_episodes, strombom_herder,
                                        wilson_interval)
from herd_ros.herding.strombom import (SheepParams, ShepherdParams, herd_is_gathered,
                                       sheep_step, strombom_targets)


def test_wilson_interval_by_hand():
    z = 1.959963984540054
    lo, hi = wilson_interval(0, 40)
    assert lo == 0.0 and hi == pytest.approx(z * z / (40 + z * z))
    lo, hi = wilson_interval(20, 40)
    half = z * math.sqrt(0.25 / 40 + z * z / (4 * 1600)) / (1 + z * z / 40)
    assert (lo, hi) == pytest.approx((0.5 - half, 0.5 + half))
    assert wilson_interval(40, 40)[1] == 1.0


def test_a_sheep_step_by_hand():
    """Two sheep 10 m apart on the x axis, the dog 20 m south of the first: no noise, no
    crowding. Sheep 0: inertia (0, 1), cohesion toward sheep 1 (1, 0), flight (0, 1)."""
    p = SheepParams(n_neighbours=1, e=0.0)
    P = np.array([[[0.0, 0.0], [10.0, 0.0]]])
    H = np.array([[[0.0, 1.0], [0.0, 1.0]]])
    dog = np.array([[[0.0, -20.0]]])
    Pn, Hn = sheep_step(P, H, dog, p, np.random.default_rng(0))
    want = np.array([1.05, 0.5 + 1.0])                  # h Ĥ + c Ĉ + ρ_s R̂^s
    want /= np.linalg.norm(want)
    np.testing.assert_allclose(Hn[0, 0], want)
    np.testing.assert_allclose(Pn[0, 0], want * p.delta)
    # a sheep beyond r_s of every dog grazes: it stays put unless it draws a move
    far = np.array([[[0.0, -500.0]]])
    Pn, _ = sheep_step(P, H, far, SheepParams(n_neighbours=1, graze=0.0),
                       np.random.default_rng(0))
    np.testing.assert_allclose(Pn, P)


def test_the_shepherd_drives_a_gathered_herd_and_collects_a_straggler():
    sheep, dog = SheepParams(n_neighbours=2), ShepherdParams()
    goal = (0.0, 0.0)
    P = np.array([[[100.0, 100.0], [101.0, 100.0], [100.0, 101.0], [101.0, 101.0]]])
    assert herd_is_gathered(P, sheep.r_a).all()
    target, driving = strombom_targets(P, np.array([[[50.0, 150.0]]]), goal, sheep, dog)
    gcm = P[0].mean(0)
    np.testing.assert_allclose(target[0, 0], gcm + sheep.r_a * 2 * gcm / np.linalg.norm(gcm))
    assert driving.all()
    P[0, 3] = (140.0, 100.0)                                   # a straggler 30 m off
    target, driving = strombom_targets(P, np.array([[[50.0, 150.0]]]), goal, sheep, dog)
    gcm = P[0].mean(0)
    away = (P[0, 3] - gcm) / np.linalg.norm(P[0, 3] - gcm)
    np.testing.assert_allclose(target[0, 0], P[0, 3] + sheep.r_a * away)
    assert not driving.any()


def test_strombom_reproduces_the_regime_of_the_paper():
    """Near-certain success when each sheep is drawn to half the herd, failure when
    cohesion is short-range (N = 14, one shepherd, e = 0.3; 60 paired episodes)."""
    cohesive = run_episodes(Setting(14, 1, 0.3), strombom_herder, range(60))
    short = run_episodes(Setting(14, 1, 0.3, n_neighbours=2), strombom_herder, range(60))
    lo, _ = wilson_interval(int(cohesive['success'].sum()), 60)
    _, hi = wilson_interval(int(short['success'].sum()), 60)
    assert lo > 0.8 and hi < 0.25, (cohesive['success'].mean(), short['success'].mean())
    assert short['mean_spread'].mean() > 3 * cohesive['mean_spread'].mean()


def test_herding_command_writes_the_summary_figure_and_gif(tmp_path, capsys):
    out = tmp_path / 'h'
    assert main(['herding', '--out', str(out), '--animals', '14', '--neighbours', 'half,3',
                 '--seeds', '6']) == 0
    summary = json.loads((out / 'summary.json').read_text())
    assert len(summary['runs']) == 2
    row = summary['runs'][0]
    assert set(row) >= {'herder', 'success', 'ci', 'median_time_s', 'mean_spread_m',
                        'max_spread_m', 'herder_path_m', 'seeds', 'setting'}
    assert row['seeds'] == list(range(6)) and row['ci'][0] <= row['success'] <= row['ci'][1]
    assert (out / 'success.png').stat().st_size > 5000
    assert (out / 'episode.gif').stat().st_size > 5000
    capsys.readouterr()
    assert main(['herding', '--out', str(out), '--herder', 'wolf']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'wolf' in err[0]


def test_herding_command_runs_the_model_herder_with_and_without_the_online_refit(tmp_path):
    out = tmp_path / 'm'
    assert main(['herding', '--out', str(out), '--animals', '6', '--herder',
                 'model,model-offline', '--seeds', '2', '--no-gif']) == 0
    rows = json.loads((out / 'summary.json').read_text())['runs']
    assert [r['herder'] for r in rows] == ['model', 'model-offline']


@pytest.fixture(scope='module')
def learned():
    from herd_ros.herding.model_herder import learn_response, record_episodes
    return learn_response(record_episodes(Setting(14, 1, 0.3)))


def test_the_learned_response_flees_the_dog(learned):
    """Strömbom's sheep flee a dog within r_s = 65 m: the learned mean response H̄(d) to
    the dog is negative (away from it) over 5–50 m, and the fit kept the dog's profile."""
    d = np.linspace(5.0, 50.0, 10)
    assert (np.interp(d, learned.grid, learned.to_dog) < 0).all()
    assert learned.choices['own_profile_agents'] == ['dog']


def test_the_model_herder_is_not_worse_than_strombom(learned):
    """30 paired episodes (N = 14, n = 7, e = 0.3): success within Strömbom's interval and
    median time at most 10 % longer (issue 27, acceptance 2's first half)."""
    from herd_ros.herding.model_herder import ModelHerder
    st = Setting(14, 1, 0.3)
    base = run_episodes(st, strombom_herder, range(30))
    ours = run_episodes(st, ModelHerder(learned), range(30))
    k0, k1 = int(base['success'].sum()), int(ours['success'].sum())
    lo, hi = wilson_interval(k0, 30)
    assert k1 / 30 >= lo, (k0, k1)
    t0 = np.median(base['steps'][base['success']])
    t1 = np.median(ours['steps'][ours['success']])
    assert t1 <= 1.1 * t0, (t0, t1)


def test_animals_of_the_other_family_are_herded_too():
    st = Setting(14, 1, 0.3, family='herd-law')
    result = run_episodes(st, strombom_herder, range(8))
    assert result['success'].mean() >= 0.75


def test_the_model_herder_drives_a_herd_that_never_gathers():
    """Cohesion n = 6 of 14 (below half the herd): the herd never comes within r_a N^(2/3)
    of its centre, so Strömbom's shepherd collects for ever; the model herder drives the
    loose herd in. 30 paired episodes, Wilson intervals apart (issue 27, acceptance 2)."""
    from herd_ros.cli.herding import model_herder
    st = Setting(14, 1, 0.3, 6)
    base = run_episodes(st, strombom_herder, range(30))
    ours = run_episodes(st, model_herder(st), range(30))
    k0, k1 = int(base['success'].sum()), int(ours['success'].sum())
    assert wilson_interval(k0, 30)[1] < wilson_interval(k1, 30)[0], (k0, k1)
