"""Hostile files, table-driven (issue: scale and hardening, acceptance 4): every reader and
verb answers with one line naming the file (and the line where there is one), exit status 2,
no traceback, and nothing written."""
import numpy as np
import pytest

from herd_ros.cli.main import main

GPS = 'time,agent,lat,lon\n'
FILES = {
    'binary': (lambda: bytes(np.random.default_rng(0).integers(0, 256, 3000, dtype=np.uint8)),
               'binary'),
    'latin-1': (lambda: (GPS + '0,caf\xe9,48.1,11.5\n1,caf\xe9,48.1,11.5\n').encode('latin-1'),
                'line 2'),
    'empty': (lambda: b'', 'empty'),
    'header only': (lambda: GPS.encode(), 'no data rows'),
    'truncated last row': (lambda: (GPS + '0,a,48.1,11.5\n1,b,48.1,11.6\n2,a,48.1\n').encode(),
                           'line 4: 3 fields'),
    'extra field': (lambda: (GPS + '0,a,48.1,11.5,7\n').encode(), 'line 2: 5 fields'),
    'semicolons': (lambda: b'time;agent;lat;lon\n0;a;48.1;11.5\n1;b;48.1;11.6\n', 'semicolons'),
    'latitude out of range': (lambda: (GPS + '0,a,148.1,11.5\n1,b,48.1,11.6\n').encode(),
                              'line 2: lat is 148.1'),
    'not a number': (lambda: (GPS + '0,a,north,11.5\n1,b,48.1,11.6\n').encode(), 'line 2'),
    'unknown format': (lambda: b'hello\nworld\n', 'cannot tell the format'),
    'trajectory cut short': (lambda: b'time,agent,x,y\n0,a,1,2\n1,a,2\n', 'line 3: 3 fields'),
}


def _model(tmp_path):
    from herd_ros.model.herd_model import AgentLaw, HerdModel
    from herd_ros.model.model_file import save_model
    from herd_ros.model.rbf_field import RbfBasis
    laws = {a: AgentLaw(damping=0.5, neighbors=[b], theta1=[0.0], theta2=[0.0],
                        basis=RbfBasis([[0.0, 0.0]], [10.0]), field_u=[0.0], field_v=[0.0],
                        noise_cov=np.eye(2)) for a, b in (('a', 'b'), ('b', 'a'))}
    save_model(HerdModel(agents=['a', 'b'], dt=1.0, laws=laws), tmp_path / 'm.yaml')
    return tmp_path / 'm.yaml'


VERBS = {
    'fit': lambda f, t: ['fit', f, '-o', t / 'out.yaml'],
    'ingest': lambda f, t: ['ingest', f, '-o', t / 'out.csv'],
    'import': lambda f, t: ['import', f, '-o', t / 'out_bag'],
    'predict': lambda f, t: ['predict', _model(t), f, '-o', t / 'out.csv'],
    'report': lambda f, t: ['report', _model(t), f, '--out', t / 'out_report'],
    'simulate --initial': lambda f, t: ['simulate', _model(t), '--initial', f,
                                        '-o', t / 'out.csv'],
}


@pytest.mark.parametrize('verb', sorted(VERBS))
@pytest.mark.parametrize('case', sorted(FILES))
def test_hostile_file_is_one_clear_line(case, verb, tmp_path, capsys):
    make, expected = FILES[case]
    if verb == 'import' and case == 'trajectory cut short':
        expected = 'planar positions'           # import needs latitude/longitude
    path = tmp_path / 'hostile.csv'
    path.write_bytes(make())
    status = main([str(a) for a in VERBS[verb](path, tmp_path)])
    out, err = capsys.readouterr()
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert status == 2, (case, verb, out, err)
    assert len(lines) == 1 and 'Traceback' not in err, (case, verb, err)
    assert lines[0].startswith(f'herd-ros {verb.split()[0]}: error: '), lines[0]
    assert 'hostile.csv' in lines[0] and expected in lines[0], lines[0]
    assert not any(p.name.startswith('out') for p in tmp_path.iterdir()), 'wrote output'
