"""The column-wise CSV text writer against Python's own formatting (the reference)."""
import numpy as np
import pytest

from herd_ros.io.csv_bytes import fixed_point, join_rows, text_field
from herd_ros.trajectory import HerdTrajectory, write_trajectory_csv

# halves, values whose scaled product lies a rounding error from a half, signed zeros,
# tiny negatives (Python writes -0.000000), large and non-finite values
EDGE = [0.0, -0.0, -1e-9, 5e-7, 2.5e-7, 1.0000005, 0.0000015, 123.4565, 0.125, -2.5,
        999999.9999995, 9.9999995, 1e9, -3e12, 1.7e9 + 0.25, np.nan, np.inf, -np.inf,
        2.0 ** 53, 1e-300]


@pytest.mark.parametrize('decimals', [0, 1, 3, 6, 9])
def test_fixed_point_is_pythons_text(decimals):
    rng = np.random.default_rng(decimals)
    v = np.concatenate([rng.normal(0, 300, 20000), rng.normal(0, 1e-5, 2000),
                        np.round(rng.normal(0, 100, 2000), decimals) + 0.5 * 10.0 ** -decimals,
                        EDGE])
    got = join_rows([fixed_point(v, decimals)]).decode().split('\n')[:-1]
    want = ['%.*f' % (decimals, x) for x in v]
    assert got == want


def test_rows_join_text_and_numbers():
    buf, mask = text_field(['cow_1', 'ß', ''])
    text = join_rows([(buf, mask), fixed_point([1.5, -2.25, 0.0], 2)]).decode()
    assert text == 'cow_1,1.50\nß,-2.25\n,0.00\n'


def test_trajectory_csv_is_the_python_formatted_table(tmp_path):
    rng = np.random.default_rng(4)
    pos = rng.normal(0, 500, (50, 7, 2))
    pos[rng.random((50, 7)) < 0.1] = np.nan                  # missing agent-ticks
    runs = [HerdTrajectory(1.7e9 + 0.5 * np.arange(50), [f'cow_{i}' for i in range(7)], pos,
                           run)
            for run in ('day 1', 'day 2')]
    path = write_trajectory_csv(tmp_path / 't.csv', runs)
    want = ['run,time,agent,x,y']
    for r in runs:
        for k, t in enumerate(r.times):
            for i, a in enumerate(r.agents):
                if np.isfinite(r.positions[k, i]).all():
                    want.append('%s,%.6f,%s,%.6f,%.6f' % (r.run, t, a, *r.positions[k, i]))
    assert path.read_text().splitlines() == want


def test_a_nul_in_a_name_is_refused_by_the_fast_path_and_written_by_pandas(tmp_path):
    with pytest.raises(ValueError, match='NUL'):
        text_field(['cow\0one'])
    run = HerdTrajectory(np.array([0.0, 1.0]), ['cow\0one', 'cow_2'],
                         np.array([[[1.0, 2.0], [3.0, 4.0]], [[5.0, 6.0], [7.0, 8.0]]]))
    lines = write_trajectory_csv(tmp_path / 't.csv', run).read_text().splitlines()
    assert lines[1] == '0.000000,cow\0one,1.000000,2.000000'
    assert len(lines) == 5
