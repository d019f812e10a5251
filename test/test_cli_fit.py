"""`herd-ros fit` / `simulate` / `synth` / `report` end to end, and bad input as one clear line."""
import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from conftest import REPO
from herd_ros.cli.main import main
from herd_ros.model.model_file import load_model
from herd_ros.trajectory import read_trajectory_csv

HEADER = 'time,agent,x,y\n'


def run_cli(argv, capsys):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture(scope='module')
def known_data(tmp_path_factory):
    d = tmp_path_factory.mktemp('known')
    assert main(['synth', '--law', 'schwager', '--agents', '3', '--steps', '4000', '--seed', '3',
                 '-o', str(d / 'data.csv'), '--truth-out', str(d / 'truth.yaml')]) == 0
    return d


def test_fit_simulate_report_round_trip(known_data, tmp_path, capsys):
    model_path = tmp_path / 'model.yaml'
    status, out, _ = run_cli(['fit', known_data / 'data.csv', '-o', model_path, '--grid', '6x6',
                              '--terms', 'full', '--ridge', '0', '--bounds=-75,75,-75,75',
                              '--report', tmp_path / 'rep'], capsys)
    assert status == 0
    assert 'constant velocity' in out and 'agent_1' in out
    # the synthetic herd's noise is independent per animal: nothing shared, at any window
    assert 'residuals shared by the herd' in out and 'moves together' not in out
    shared = json.loads((tmp_path / 'rep' / 'summary.json').read_text())['shared_residuals']
    assert shared['window_s'] and all(abs(c) < 0.1 for c in shared['correlation'])
    doc = yaml.safe_load(model_path.read_text())
    body = doc['/**']['ros__parameters']['model']
    assert body['kind'] == 'schwager2007' and body['agents'] == ['agent_1', 'agent_2', 'agent_3']
    law = body['agent_1']
    n_theta = 1 + 2 * len(law['neighbors']) + 2 * len(law['field_u'])
    assert len(law['theta_se']) == n_theta and len(law['noise_cov']) == 4
    for name in ('fig2_interaction', 'fig3_field', 'fig4_whiteness', 'fig5_trajectories',
                 'fig6_statistics'):
        assert (tmp_path / 'rep' / f'{name}.png').stat().st_size > 10_000
    status, out, _ = run_cli(['simulate', model_path, '--steps', '500', '--seed', '1',
                              '-o', tmp_path / 'sim.csv'], capsys)
    assert status == 0
    sim = read_trajectory_csv(tmp_path / 'sim.csv')[0]
    assert sim.positions.shape == (500, 3, 2) and np.isfinite(sim.positions).all()
    status, out, _ = run_cli(['report', model_path, known_data / 'data.csv',
                              '--out', tmp_path / 'rep2'], capsys)
    assert status == 0 and (tmp_path / 'rep2' / 'summary.json').exists()


def test_fit_reads_the_shipped_bag_and_a_gps_csv(tmp_path, capsys):
    bag = REPO / 'bags' / 'cows_3x1h'
    status, out, err = run_cli(['fit', bag, '--dt', '10', '--accel-std', '0.02',
                                '-o', tmp_path / 'cows.yaml', '--grid', '6x6'], capsys)
    assert status == 0, err
    model = load_model(tmp_path / 'cows.yaml')
    assert model.agents == ['cow_1', 'cow_2', 'cow_3'] and model.dt == 10.0
    assert model.datum is not None and abs(model.datum[0] - 27.0153) < 0.01
    status, _, err = run_cli(['synth', '--scenario', 'cows', '--agents', '3', '--duration', '1800',
                              '-o', tmp_path / 'truth.csv', '--gps-out', tmp_path / 'gps.csv'],
                             capsys)
    assert status == 0, err
    status, out, err = run_cli(['fit', tmp_path / 'gps.csv', '--dt', '10', '--grid', '4x4',
                                '-o', tmp_path / 'gps_model.yaml'], capsys)
    assert status == 0, err


def _write(path, rows, header=HEADER):
    path.write_text(header + ''.join(rows))
    return path


def _steps(n=50, agents=('a', 'b'), dt=1.0, skip=None):
    rng = np.random.default_rng(0)
    rows = []
    for k in range(n):
        for j, a in enumerate(agents):
            if skip == (k, a):
                continue
            rows.append(f'{k * dt},{a},{10 * j + rng.normal()},{rng.normal()}\n')
    return rows


BAD = {
    'unsorted rows': lambda p: _write(p, _steps()[:10][::-1] + _steps()[10:]),
    'duplicate timestamps': lambda p: _write(p, _steps()[:4] + _steps()[2:]),
    'co-located agents': lambda p: _write(p, [f'{k},{a},1.0,2.0\n' for k in range(50)
                                                for a in 'ab']),
    'NaN': lambda p: _write(p, _steps()[:5] + ['5,a,nan,1\n'] + _steps()[6:]),
    'fewer samples than parameters': lambda p: _write(p, _steps(n=6)),
    'missing column': lambda p: _write(p, ['0,a,1\n'], header='time,agent,x\n'),
    'not a file': lambda p: p.parent / 'nope.csv',
    # ids that are no ROS names are made so (herd_ros.agent_ids); two that would merge
    'agent ids that would become one ROS name': lambda p: _write(
        p, _steps(agents=('cow 1', 'cow_1'))),
    'agent only in the held-out part': lambda p: _write(p, _steps(agents=('a', 'b'))
                                                        + [f'{k},c,5,5\n'
                                                           for k in range(45, 50)]),
}


@pytest.mark.parametrize('case', sorted(BAD))
def test_bad_input_is_one_clear_line(case, tmp_path, capsys):
    data = BAD[case](tmp_path / 'bad.csv')
    # the full model forced: with selection a short file gets the damping-only model
    status, out, err = run_cli(['fit', data, '-o', tmp_path / 'm.yaml', '--grid', '2x2',
                                '--terms', 'full', '--min-visits', '1'], capsys)
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert status == 2, (case, out, err)
    assert len(lines) == 1 and lines[0].startswith('herd-ros fit: error: '), (case, err)
    assert 'Traceback' not in err
    assert not (tmp_path / 'm.yaml').exists()


def test_installed_command_reports_errors_without_traceback(tmp_path, console_script):
    bad = BAD['NaN'](tmp_path / 'bad.csv')
    proc = subprocess.run([console_script('herd-ros'), 'fit', str(bad), '-o',
                           str(tmp_path / 'm.yaml')], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count('\n') == 0 and 'line 7' in proc.stderr, proc.stderr
    help_text = subprocess.run([console_script('herd-ros'), '--help'], capture_output=True,
                               text=True, timeout=60).stdout
    for verb in ('fit', 'simulate', 'report', 'synth', 'import', 'imitate', 'flock', 'demo'):
        assert verb in help_text


def test_the_overview_help_lists_every_verb_without_importing_them(capsys):
    """``herd-ros --help`` reads each verb's one line from its module's source (no verb
    module imported: 1.5 s for all of them), and each line is the module's ``HELP``."""
    import importlib
    import sys

    from herd_ros.cli.main import VERBS, overview_parser, verb_help
    before = {m for m in sys.modules if m.startswith('herd_ros.cli.')}
    with pytest.raises(SystemExit) as exit_:
        overview_parser().parse_args(['--help'])
    assert exit_.value.code == 0
    assert {m for m in sys.modules if m.startswith('herd_ros.cli.')} == before
    text = ' '.join(capsys.readouterr().out.split())
    for verb, module_name in VERBS.items():
        line = importlib.import_module(f'herd_ros.cli.{module_name}').HELP
        assert verb_help(module_name) == line
        assert ' '.join(line.split()) in text, verb


def test_a_verbs_help_does_not_import_the_numerics(tmp_path):
    """``herd-ros VERB --help`` builds only the verb's options: for every verb neither
    pandas, scipy, numba nor rclpy is imported (fit's --help took 2.1 s with them, 0.25 s
    without; flock's 1.0 s, 0.24 s), and the help still names the defaults that come from
    the fit's candidate sets."""
    from herd_ros.cli.main import VERBS
    verbs = list(VERBS)
    code = (
        'import contextlib, io, sys\n'
        'from herd_ros.cli.main import _main\n'
        'heavy = ("pandas", "scipy", "numba", "rclpy", "matplotlib")\n'
        f'for verb in {verbs!r}:\n'
        '    out = io.StringIO()\n'
        '    with contextlib.redirect_stdout(out):\n'
        '        try:\n'
        '            _main([verb, "--help"])\n'
        '        except SystemExit as e:\n'
        '            assert e.code == 0, verb\n'
        '    assert "usage: herd-ros " + verb in out.getvalue(), verb\n'
        '    if verb == "fit":\n'
        '        print(" ".join(out.getvalue().split()))\n'
        '    print(verb, [m for m in heavy if m in sys.modules])\n')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    for verb in verbs:
        assert f'{verb} []' in lines, proc.stdout
    fit_help = lines[0]
    assert 'among 4/16/64 cells' in fit_help and '0, 0.001, 0.01, 0.1' in fit_help
    assert '0.6, 0.35, 0.2' in fit_help and 'up to 6 agents' in fit_help


def test_missing_rows_are_missing_positions_not_errors(tmp_path, capsys):
    """A stale collar has no row at some steps: the fit skips the samples that need it."""
    data = _write(tmp_path / 'gappy.csv', _steps(skip=(7, 'b')))
    status, out, err = run_cli(['fit', data, '-o', tmp_path / 'm.yaml', '--grid', '2x2',
                                '--min-visits', '1'], capsys)
    assert status == 0, err


def test_irregular_planar_fixes_go_through_the_ingest(tmp_path, capsys):
    """Irregular stamps (RTLS/UWB positions in metres) are fixes: filtered onto a clock."""
    rows = [r.replace(r.split(',')[0], str(float(r.split(',')[0]) + 0.37 * (j % 2)), 1)
            for j, r in enumerate(_steps(n=80))]
    data = _write(tmp_path / 'rtls.csv', rows)
    status, out, err = run_cli(['fit', data, '-o', tmp_path / 'm.yaml', '--grid', '2x2',
                                '--min-visits', '1'], capsys)
    assert status == 0, err


def _damping_only_model(tmp_path, a=(0.8, 0.5), q=(0.04, 0.09)):
    """A hand-made damping-only model file (field weight 0, no pair terms)."""
    from herd_ros.model.herd_model import AgentLaw, HerdModel
    from herd_ros.model.rbf_field import RbfBasis
    laws = {}
    for name, other, ak, qk in (('a', 'b', a[0], q[0]), ('b', 'a', a[1], q[1])):
        laws[name] = AgentLaw(damping=ak, neighbors=[other], theta1=[0.0], theta2=[0.0],
                              basis=RbfBasis([[0.0, 0.0]], [10.0]), field_u=[0.0],
                              field_v=[0.0], noise_cov=np.diag([qk, qk]))
    from herd_ros.model.model_file import save_model
    path = tmp_path / 'hand.yaml'
    save_model(HerdModel(agents=['a', 'b'], dt=2.0, laws=laws), path)
    return path


@pytest.mark.parametrize('k', [1, 2])
def test_predict_writes_hand_computed_positions_and_covariances(tmp_path, capsys, k):
    """p̂^{s+1} = p^s + a (p^s − p^{s−1}); p̂^{s+2} = p^s + (a + a²)(p^s − p^{s−1}); the
    covariance Δt² Q (k = 1) and Δt² ((1 + a)² + 1) Q (k = 2) at the first prediction,
    where no residual has been seen yet (noise level 1)."""
    model = _damping_only_model(tmp_path)
    rng = np.random.default_rng(1)
    T = 12
    pos = np.cumsum(rng.normal(size=(T, 2, 2)), axis=0)
    rows = [f'{2.0 * t},{ag},{pos[t, i, 0]},{pos[t, i, 1]}\n'
            for t in range(T) for i, ag in enumerate('ab')]
    data = _write(tmp_path / 'd.csv', rows)
    status, out, err = run_cli(['predict', model, data, '-o', tmp_path / 'p.csv',
                                '--steps', k], capsys)
    assert status == 0, err
    import pandas as pd
    pred = pd.read_csv(tmp_path / 'p.csv')
    assert list(pred.columns) == ['time', 'agent', 'x', 'y', 'cov_xx', 'cov_xy', 'cov_yy']
    assert len(pred) == 2 * (T - k - 1)
    for i, (ag, a, q) in enumerate((('a', 0.8, 0.04), ('b', 0.5, 0.09))):
        mine = pred[pred.agent == ag].sort_values('time')
        gain = a if k == 1 else a + a * a
        for t_row, row in zip(range(k + 1, T), mine.itertuples()):
            s = t_row - k
            expected = pos[s, i] + gain * (pos[s, i] - pos[s - 1, i])
            assert row.time == 2.0 * t_row
            np.testing.assert_allclose([row.x, row.y], expected, atol=1e-5)
        first = mine.iloc[0]
        var = 4.0 * q * (1.0 if k == 1 else (1 + a) ** 2 + 1)
        assert first.cov_xx == pytest.approx(var, rel=1e-5) and first.cov_xy == 0.0
    assert 'inside the 90 % prediction ellipse' in out
    # beside the naive predictors on the same positions: stay-put p^{t−k}, constant velocity
    # p^{t−k} + k (p^{t−k} − p^{t−k−1}), by hand
    t = np.arange(k + 1, T)
    stay = np.sqrt(np.mean(((pos[t - k] - pos[t]) ** 2).sum(-1)))
    cv = np.sqrt(np.mean(((pos[t - k] + k * (pos[t - k] - pos[t - k - 1]) - pos[t]) ** 2)
                         .sum(-1)))
    assert (f'on the {2 * len(t)} positions every predictor reaches: model ' in out
            and f'stay-put {stay:.3f}, constant velocity {cv:.3f}' in out), out


def test_predict_refuses_data_without_the_models_agents(tmp_path, capsys):
    model = _damping_only_model(tmp_path)
    data = _write(tmp_path / 'd.csv', [f'{t},a,{t},0\n' for t in range(6)]
                  + [f'{t},c,0,{t}\n' for t in range(6)])
    status, _, err = run_cli(['predict', model, data, '-o', tmp_path / 'p.csv'], capsys)
    assert status == 2 and 'no data for agent(s) b' in err


def test_simulate_starts_a_late_agent_where_it_is_first_seen(tmp_path, capsys):
    """Real recordings start with collars missing: the simulation takes each agent's first
    two consecutive positions (here b appears at step 2), not NaN."""
    model = _damping_only_model(tmp_path)
    rows = [f'{2.0 * t},a,{float(t)},0\n' for t in range(6)] + \
        [f'{2.0 * t},b,0,{10.0 + t}\n' for t in range(2, 6)]
    data = _write(tmp_path / 'late.csv', rows)
    status, out, err = run_cli(['simulate', model, '--steps', '5', '--no-noise', '--initial',
                                data, '-o', tmp_path / 'sim.csv'], capsys)
    assert status == 0, err
    sim = read_trajectory_csv(tmp_path / 'sim.csv')[0]
    np.testing.assert_allclose(sim.positions[0], [[0.0, 0.0], [0.0, 12.0]])
    # damping only, no noise: u^1 = a u^0, p^1 = p^0 + Δt u^0
    np.testing.assert_allclose(sim.positions[1], [[1.0, 0.0], [0.0, 13.0]])
    np.testing.assert_allclose(sim.positions[2], [[1.0 + 0.8, 0.0], [0.0, 13.5]])


def test_simulate_compares_with_its_initial_trajectory_seen_like_it(tmp_path, capsys):
    """With --initial on the model's clock, simulate prints the free-run statistics against
    it (the run seen where the data are) and, with --seen-like-initial, writes each agent
    only where the data have it: b starts late and is silent at steps 5-6."""
    model = _damping_only_model(tmp_path)
    rows = [f'{2.0 * t},a,{float(t)},0\n' for t in range(12)] + \
        [f'{2.0 * t},b,0,{10.0 + t}\n' for t in range(2, 12) if t not in (5, 6)]
    data = _write(tmp_path / 'gappy.csv', rows)
    status, out, err = run_cli(['simulate', model, '--steps', '10', '--no-noise', '--initial',
                                data, '-o', tmp_path / 'sim.csv', '--seen-like-initial'], capsys)
    assert status == 0, err
    assert 'against' in out and 'over 10 steps' in out and 'the run seen where the data are' \
        in out and '(each agent where the initial trajectory has it)' in out
    sim = read_trajectory_csv(tmp_path / 'sim.csv')[0]
    present = np.isfinite(sim.positions).all(-1)
    assert present[:, 0].all()
    assert present[:, 1].tolist() == [False, False, True, True, True, False, False, True,
                                      True, True]
    status, _, err = run_cli(['simulate', model, '--steps', '10', '-o', tmp_path / 's.csv',
                              '--seen-like-initial'], capsys)
    assert status == 2 and '--seen-like-initial needs --initial' in err


def test_fit_long_run_terms_write_the_field_and_regimes_and_simulate_uses_them(tmp_path, capsys):
    """`fit --field space-use --noise regimes` on two agents whose noise switches between
    resting and moving (u' = a u + w): the file carries the regimes and a space-use field,
    `simulate` runs from it; the online fit refuses the options with one line."""
    rng = np.random.default_rng(4)
    n = 6000
    cov = np.array([1e-5 * np.eye(2), 0.02 * np.eye(2)])
    trans = np.array([[0.95, 0.05], [0.1, 0.9]])
    rows = []
    for k, a in enumerate((0.6, 0.4)):
        z, u, p = 0, np.zeros(2), np.array([10.0 * k, 0.0])
        for t in range(n):
            z = rng.choice(2, p=trans[z])
            u = a * u + np.linalg.cholesky(cov[z]) @ rng.standard_normal(2) - 0.002 * p
            p = p + u
            rows.append(f'{t}.0,agent_{k + 1},{p[0]:.5f},{p[1]:.5f}\n')
    data = tmp_path / 'stopgo.csv'
    data.write_text(HEADER + ''.join(sorted(rows, key=lambda r: float(r.split(',')[0]))))
    model_path = tmp_path / 'm.yaml'
    status, out, _ = run_cli(['fit', data, '-o', model_path, '--terms', 'damping',
                              '--field', 'space-use', '--noise', 'regimes'], capsys)
    assert status == 0
    assert 'noise regimes: BIC keeps' in out and 'space-use field' in out
    assert 'simulated herd vs training data' in out
    body = yaml.safe_load(model_path.read_text())['/**']['ros__parameters']['model']
    k = body['selection']['noise_regimes']
    assert k in (2, 3) and f'BIC keeps {k}' in out          # the data switch; K = 1 is out
    assert len(body['noise_regime_cov']) == 2 * k * 4
    assert len(body['noise_regime_transition']) == 2 * k * k
    assert body['selection']['field'] == 'space-use'
    assert len(body['agent_1']['field_u']) > 1 and any(body['agent_1']['field_u'])
    model = load_model(model_path)
    assert model.meta['noise_regimes'][1].shape == (2, k, k)
    status, _, _ = run_cli(['simulate', model_path, '--steps', '400', '-o', tmp_path / 's.csv'],
                           capsys)
    assert status == 0
    assert np.isfinite(read_trajectory_csv(tmp_path / 's.csv')[0].positions).all()
    status, _, err = run_cli(['fit', data, '-o', tmp_path / 'x.yaml', '--online',
                              '--noise', 'regimes'], capsys)
    assert status == 2 and 'batch fit' in err and len(err.strip().splitlines()) == 1


def test_fit_alignment_on_chooses_among_the_alignment_candidates(known_data, tmp_path,
                                                                  capsys):
    """A herd without alignment: cross-validation alone would not keep it, --alignment on
    chooses among the cross-validated candidates that have it (it used to crash after the
    selection: the forced structure was in no table)."""
    model_path = tmp_path / 'aligned.yaml'
    status, out, err = run_cli(['fit', known_data / 'data.csv', '-o', model_path, '--grid',
                                '4x4', '--alignment', 'on', '--field', 'fitted', '--noise',
                                'gaussian', '--report', tmp_path / 'rep'], capsys)
    assert status == 0, err
    chosen = [line for line in out.splitlines() if '<- chosen' in line]
    assert len(chosen) == 1 and '+alignment' in chosen[0]
    summary = json.loads((tmp_path / 'rep' / 'summary.json').read_text())
    selection = summary['selection']
    assert np.isfinite(selection['cv_rms']['selected']) and selection['alignment']
