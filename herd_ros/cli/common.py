"""Small helpers shared by the command-line verbs: option parsing and progress bars."""
from __future__ import annotations

import sys

from herd_ros.errors import HerdInputError


def parse_grid(text: str) -> tuple[int, int]:
    """'8x6' -> (8, 6)."""
    try:
        nx, ny = (int(v) for v in text.lower().split('x'))
    except ValueError:
        raise HerdInputError(f'--grid takes NXxNY, e.g. 8x8, got {text!r}') from None
    if nx < 1 or ny < 1:
        raise HerdInputError(f'--grid needs positive sizes, got {text!r}')
    return nx, ny


def parse_floats(text: str, n: int | tuple[int, ...], option: str) -> tuple[float, ...]:
    """'1,2,3,4' -> (1.0, 2.0, 3.0, 4.0), checking the count."""
    try:
        values = tuple(float(v) for v in text.split(','))
    except ValueError:
        raise HerdInputError(f'{option} takes comma-separated numbers, got {text!r}') from None
    counts = (n,) if isinstance(n, int) else n
    if len(values) not in counts:
        raise HerdInputError(f'{option} takes {" or ".join(map(str, counts))} numbers, '
                             f'got {len(values)}')
    return values


def progress(total=None, desc='', unit='it'):
    """A tqdm bar on stderr; silent when stderr is not a terminal (logs, CI)."""
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False,
                dynamic_ncols=True, mininterval=0.5, disable=None)
