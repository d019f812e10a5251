"""The collar kernels compiled ahead of time (:mod:`herd_ros.ingest.aot`).

Their numbers are checked with the rest of the bank (``test_collar_bank.py`` and the batch
herd clock of ``test_herd_clock.py`` run on both compilations). Here: the extension refuses
arrays that its unchecked entry points would misread, a stale extension is never used, and
the installed package runs ``herd-ros ingest`` without importing numba at all.
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from herd_ros.ingest import aot


def predict_args(n=3):
    x = np.zeros((n, 4))
    P = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    return [x, P, np.ones(n), np.full(n, 0.1), np.zeros(n), np.empty((n, 4)),
            np.empty((n, 4, 4))]


def test_a_valid_call_predicts_as_the_motion_model(aot_kernels):
    args = predict_args()
    args[0][:] = [1.0, 2.0, 0.5, -0.25]
    aot_kernels.predict_many(*args)
    # constant velocity over 1 s: p += v; P = F I Fᵀ + Q with q = 0.1² (1/4, 1/2, 1)
    np.testing.assert_allclose(args[5], [[1.5, 1.75, 0.5, -0.25]] * 3)
    q = 0.01
    np.testing.assert_allclose(args[6][0, 0, [0, 2]], [2 + q / 4, 1 + q / 2])
    np.testing.assert_allclose(args[6][0, 2, 2], 1 + q)


@pytest.mark.parametrize('k,bad,words', [
    (2, np.ones(3, np.float32), 'float32'),                  # would crash the process
    (2, np.ones(6)[::2], 'not C-contiguous'),                # would be read as contiguous
    (0, np.zeros((3, 4, 1)), '3-d'),
    (0, [[0.0] * 4] * 3, 'list'),
])
def test_entry_points_refuse_what_they_would_misread(aot_kernels, k, bad, words):
    args = predict_args()
    args[k] = bad
    with pytest.raises(TypeError, match=f'predict_many: argument {k} must be .*{words}'):
        aot_kernels.predict_many(*args)


def test_outputs_must_be_writable_inputs_need_not(aot_kernels):
    args = predict_args()
    for a in args[:3]:
        a.flags.writeable = False                    # e.g. pandas' read-only views
    aot_kernels.predict_many(*args)
    args[5].flags.writeable = False
    with pytest.raises(TypeError, match='argument 5 must be a C-contiguous writable'):
        aot_kernels.predict_many(*args)
    with pytest.raises(TypeError, match='takes 7 arguments, got 6'):
        aot_kernels.predict_many(*args[:6])


def test_only_an_extension_built_from_these_sources_is_used(aot_kernels, monkeypatch):
    monkeypatch.setitem(sys.modules, f'herd_ros.ingest.{aot.EXTENSION}', aot_kernels.module)
    assert aot.load_kernels('auto').kind == 'aot'
    assert aot.load_kernels('jit').kind == 'jit'
    monkeypatch.setattr(aot, 'source_digest', lambda: aot_kernels.module.source_digest() + 1)
    with pytest.warns(RuntimeWarning, match='built from other sources'):
        assert aot.load_kernels('auto').kind == 'jit'
    with pytest.raises(ImportError, match='not built'), pytest.warns(RuntimeWarning):
        aot.load_kernels('aot')
    monkeypatch.setenv(aot.ENV, 'fast')
    with pytest.raises(ValueError, match='auto, aot or jit'):
        aot.load_kernels()


def test_installed_ingest_runs_without_numba(aot_kernels, tmp_path):
    """``make test`` installs the package (setup.py builds the extension): the installed
    ``herd-ros ingest`` path loads no numba (and so no scipy) and gives the numbers the JIT
    gives."""
    src = tmp_path / 'fixes.csv'
    rng = np.random.default_rng(0)
    rows = ['time,agent,lat,lon']
    for k in range(200):
        for a in range(3):
            lat = 27.0 + 1e-5 * k + rng.normal(0, 2e-5)
            lon = -108.8 + 1e-5 * a + rng.normal(0, 2e-5)
            rows.append(f'{1.7e9 + 5 * k + a:.1f},cow_{a},{lat:.8f},{lon:.8f}')
    src.write_text('\n'.join(rows) + '\n')
    script = ('import json, sys\n'
              'from herd_ros.ingest import collar_bank\n'
              'from herd_ros.ingest.pipeline import load_fixes, trajectory_from_fixes\n'
              f'traj = trajectory_from_fixes(load_fixes({str(src)!r}), 5.0)\n'
              'print(json.dumps([collar_bank.KERNELS.kind, "numba" in sys.modules,\n'
              '                  "scipy" in sys.modules, collar_bank.__file__,\n'
              '                  traj.positions.tolist()]))\n')
    env = {k: v for k, v in os.environ.items() if k not in ('PYTHONPATH', aot.ENV)}
    out = subprocess.run([sys.executable, '-c', script], cwd=tmp_path, env=env, check=True,
                         capture_output=True, text=True)
    kind, numba, scipy, where, aot_positions = json.loads(out.stdout)
    assert aot.Path(where).resolve().parent != aot.Path(aot.__file__).resolve().parent, \
        f'the source tree was imported ({where}), not the installed package'
    assert (kind, numba, scipy) == ('aot', False, False), \
        f'{where}: kernels {kind}, numba imported {numba}, scipy imported {scipy}'
    out = subprocess.run([sys.executable, '-c', script], cwd=tmp_path,
                         env={**env, aot.ENV: 'jit'}, check=True, capture_output=True,
                         text=True)
    kind, numba, _, _, jit_positions = json.loads(out.stdout)
    assert (kind, numba) == ('jit', True)
    np.testing.assert_array_equal(np.array(aot_positions, float),
                                  np.array(jit_positions, float))
