"""Which environment field and which noise a law gets, judged by how it runs freely
(issue 30).

Cross-validation of the one-step error chooses the structure (:mod:`model_selection`); one
step ahead, a field that keeps each animal in its range earns little, so it is left out —
and the law, run freely, lets the herd drift apart (the steers: distance +364 %). The
space-use field (:mod:`herd_ros.model.space_use_field`) makes each animal spend its time
where it did; it can cost one-step skill (the baboons' troop travels: a fixed field pulls it
back). So the choice is made on data the fit has not seen, a validation tail of the
training data, on both counts (a split-sample check: the law is fitted on the first
:data:`FIT_FRACTION` of every training run and judged on the rest):

* the free-run error: the largest |log(run / data)| over the herd's distance, spread and
  pace (:func:`~herd_ros.simulation.free_run.free_run_fidelity`, median of the seeds);
* the one-step RMS.

Each agent's place in the herd (:mod:`herd_ros.model.herd_place`: the pull at the edge of
the range of its offset from the others' centroid) holds a herd together when its law alone
lets it drift apart (ten penned steers over two hours: distance +44 to +145 % of the
held-out hour without it); where the places change between the training data and the
rest (a baboon troop leaving its sleeping site) it pulls the law to places the herd has
left, and binding animals whose noise is independent slows the herd's common motion (the
baboons' first half: pace −60 %). They are tried only for a law whose free-run error is
above :data:`PLACE_NEEDED` and kept when they bring the free-run error down to
:data:`PLACE_GAIN` of the law's without them, make no statistic worse by more than
:data:`PLACE_WORSE` and are at most :data:`ONE_STEP_TOLERANCE` worse one step ahead
(:func:`choose_herd_place`; capped, (P2) of :mod:`~herd_ros.model.herd_place`, they cannot be
much worse).

Noise regimes (stop-and-go noise, :mod:`herd_ros.model.noise_regimes`) change nothing one
step ahead (the mean prediction is the same); they are kept when they make the free run
clearly closer on all of :data:`~herd_ros.simulation.free_run.STATISTICS` (the error falls
below :data:`REGIMES_GAIN` of the Gaussian noise's) without making the herd's shape worse
(its :data:`SHAPE` error at most :data:`SHAPE_SLACK` times the Gaussian noise's) —
:func:`choose_noise_regimes`.

The space-use field is kept only where the fitted law clearly fails to run freely (its
free-run error above :data:`CLEAR_FAILURE`: a statistic off by more than half) and the
space-use field at least halves that error at most :data:`ONE_STEP_TOLERANCE` worse one
step ahead. A law that already runs about right keeps its fitted field (on the known-truth
herds the field fitted is the true one).
"""
from __future__ import annotations

import numpy as np

#: the fitted share of each training run; the rest judges the fields
FIT_FRACTION = 0.8
#: how much worse (relative) the one-step RMS may get for a better free run
ONE_STEP_TOLERANCE = 0.02
#: a free-run error (max |log ratio|) beyond which the fitted law clearly fails: ×1.5 or ÷1.5
CLEAR_FAILURE = float(np.log(1.5))
#: noise regimes are kept when their free-run error is below this share of Gaussian noise's
REGIMES_GAIN = 0.8
#: how much worse the shape error may get with noise regimes (their gain is in the speeds)
SHAPE_SLACK = 1.1
#: herd places are kept when their free-run error is at most this share of the law's without
#: them (and one step ahead within :data:`ONE_STEP_TOLERANCE`)
PLACE_GAIN = 0.8
#: places are not tried for a law whose free-run error is at most this (within 10 %, about
#: what three noise seeds resolve: a known-truth law's 0.07-0.09 are noise)
PLACE_NEEDED = float(np.log(1.1))
#: ... and no statistic's error grows by more than this (|log ratio|: 25 % the wrong way);
#: places bind animals whose noise is independent, which can slow the herd's common motion
PLACE_WORSE = float(np.log(1.25))
#: noise seeds of the free runs of the check
SEEDS = 3
#: the statistics the free-run error is taken over
SHAPE = ('distance', 'spread', 'pace')


def free_run_error(result: dict, statistics=SHAPE) -> float:
    """max over ``statistics`` (default :data:`SHAPE`) of |log(median of the runs / data)|
    (the herd's); inf when a statistic is not finite or not positive."""
    worst = 0.0
    for k in statistics:
        r = result['herd'][k]
        if not (r['median'] > 0 and r['data'] > 0):
            return float('inf')
        worst = max(worst, abs(float(np.log(r['median'] / r['data']))))
    return worst


class ValidationTail:
    """The check's data, made once for the three choices: the chosen structure fitted on the
    first :data:`FIT_FRACTION` of every training run (``model``, by ``refit``: runs ->
    model), the positions it was fitted on, the tail that judges (``tail``, runs of at
    least 10 steps; the free runs start from its longest), when first asked the same
    model with the space-use field (``space_use_model``) and the herd places
    (:meth:`law`), and each law's scores on the tail (:meth:`one_step`, :meth:`free_run`:
    a law the choices share is run once)."""

    def __init__(self, train, refit):
        from herd_ros.estimation.herd_fit import aligned_positions, split_runs
        fit_part, tail = split_runs(train, FIT_FRACTION)
        self.tail = [r for r in tail if r.n_steps >= 10]
        self.model = refit(fit_part) if self.tail else None
        self.positions = ([aligned_positions(r, self.model.agents) for r in fit_part]
                          if self.tail else [])
        self._space_use = None
        self._placed = {}
        self._one_step, self._free_run = {}, {}

    @property
    def reason(self) -> str:
        """Why no choice can be made ('' when it can)."""
        return '' if self.tail else 'too little training data for a validation tail'

    @property
    def longest(self):
        """The longest run of the validation tail."""
        return max(self.tail, key=lambda r: r.n_steps)

    @property
    def space_use_model(self):
        """The law with the space-use field of the tail's training part (made once)."""
        if self._space_use is None:
            from herd_ros.model.space_use_field import with_space_use_field
            self._space_use = with_space_use_field(self.model, np.concatenate(self.positions))
        return self._space_use

    def law(self, space_use: bool = False, place: bool = False):
        """The check's law with the space-use field and/or the herd places of its training
        part (each made once; with ``place``, the law itself when no agent gets a pull)."""
        base = self.space_use_model if space_use else self.model
        if not place:
            return base
        if space_use not in self._placed:
            from herd_ros.model.herd_place import with_herd_place
            self._placed[space_use] = with_herd_place(base, np.concatenate(self.positions))
        return self._placed[space_use]

    def _key(self, space_use: bool, place: bool) -> tuple:
        return (space_use, place and self.law(space_use, True) is not self.law(space_use))

    def one_step(self, space_use: bool = False, place: bool = False) -> float:
        """The herd's one-step RMS of :meth:`law` on the tail (computed once)."""
        from herd_ros.simulation.prediction import one_step_rms
        key = self._key(space_use, place)
        if key not in self._one_step:
            self._one_step[key] = float(
                one_step_rms(self.law(*key), self.tail)['model']['herd'])
        return self._one_step[key]

    def free_run(self, space_use: bool = False, place: bool = False,
                 seeds: int = SEEDS) -> dict:
        """:func:`~herd_ros.simulation.free_run.free_run_fidelity` of :meth:`law` from the
        start of the tail's longest run (computed once: the three choices share them)."""
        from herd_ros.simulation.free_run import free_run_fidelity
        key = self._key(space_use, place) + (seeds,)
        if key not in self._free_run:
            self._free_run[key] = free_run_fidelity(self.law(*key[:2]), self.longest,
                                                    seeds=seeds)
        return self._free_run[key]


def choose_space_use(check: ValidationTail, seeds: int = SEEDS) -> tuple[bool, dict]:
    """Whether the space-use field earns its place (see the module docstring).

    Returns:
        (keep, figures) with figures {'fitted'|'space_use': {'one_step', 'free_run_error'}}
        on the validation tail, or (False, {'reason': ...}) when there is too little data.
    """
    if check.reason:
        return False, {'reason': check.reason}
    figures = {}
    for name, space_use in (('fitted', False), ('space_use', True)):
        figures[name] = {
            'one_step': check.one_step(space_use),
            'free_run_error': free_run_error(check.free_run(space_use, seeds=seeds))}
    f, s = figures['fitted'], figures['space_use']
    keep = (f['free_run_error'] > CLEAR_FAILURE
            and s['free_run_error'] <= 0.5 * f['free_run_error']
            and s['one_step'] <= (1.0 + ONE_STEP_TOLERANCE) * f['one_step'])
    figures['kept'] = bool(keep)
    return keep, figures


def choose_herd_place(check: ValidationTail, space_use: bool,
                      seeds: int = SEEDS) -> tuple[bool, dict]:
    """Whether each agent's place in the herd earns its place (see the module docstring):
    the check's law (with the space-use field when ``space_use``) without and with the
    places of its training part, on the validation tail.

    Returns (keep, figures) with figures {'without'|'with': {'one_step', 'free_run_error'}},
    or (False, {'reason': ...})."""
    if check.reason:
        return False, {'reason': check.reason}
    if check.law(space_use, place=True) is check.law(space_use):
        return False, {'reason': 'no agent has a place: too few positions, offsets that do '
                                 'not spread or no stationary law'}
    alone = free_run_error(check.free_run(space_use, seeds=seeds))
    if alone <= PLACE_NEEDED:
        return False, {'reason': f'the law runs freely within 10 % without them (free-run '
                                 f'error {alone:.2f})'}
    figures = {}
    for name, place in (('without', False), ('with', True)):
        result = check.free_run(space_use, place, seeds)
        figures[name] = {
            'one_step': check.one_step(space_use, place),
            'free_run_error': free_run_error(result),
            'errors': {k: free_run_error(result, (k,)) for k in SHAPE}}
    w, p = figures['without'], figures['with']
    keep = (p['free_run_error'] <= PLACE_GAIN * w['free_run_error']
            and all(p['errors'][k] <= w['errors'][k] + PLACE_WORSE for k in SHAPE)
            and p['one_step'] <= (1.0 + ONE_STEP_TOLERANCE) * w['one_step'])
    figures['kept'] = bool(keep)
    return keep, figures


def choose_noise_regimes(check: ValidationTail, space_use: bool, seeds: int = SEEDS,
                         place: bool = False) -> tuple:
    """Whether noise regimes earn their place (see the module docstring): the check's law
    (with the space-use field when ``space_use``, the herd places when ``place``), with
    Gaussian noise and with regimes, run freely over the validation tail.

    Returns (keep, figures) with figures {'gaussian'|'regimes': {'free_run_error',
    'shape_error'}, 'regimes_count': K}, or (False, {'reason': ...})."""
    from herd_ros.model.noise_regimes import with_noise_regimes
    from herd_ros.simulation.free_run import STATISTICS, free_run_fidelity
    if check.reason:
        return False, {'reason': check.reason}
    model = check.law(space_use, place)
    regimes, info = with_noise_regimes(model, check.positions)
    if info['n_regimes'] == 1:
        return False, {'reason': 'BIC keeps one noise level', 'regimes': 1}
    figures = {'regimes_count': int(info['n_regimes'])}
    for name, m in (('gaussian', model), ('regimes', regimes)):
        result = (check.free_run(space_use, place, seeds) if m is model
                  else free_run_fidelity(m, check.longest, seeds=seeds))
        figures[name] = {'free_run_error': free_run_error(result, STATISTICS),
                         'shape_error': free_run_error(result, SHAPE)}
    g, r = figures['gaussian'], figures['regimes']
    keep = (r['free_run_error'] < REGIMES_GAIN * g['free_run_error']
            and r['shape_error'] <= SHAPE_SLACK * g['shape_error'])
    figures['kept'] = bool(keep)
    return keep, figures



def _error(x: float) -> str:
    """A free-run error as printed: 'n/a' where a statistic of the run or the data is zero
    or undefined (:func:`free_run_error` is then inf)."""
    return f'{x:.2f}' if np.isfinite(x) else 'n/a'


def describe_choice(name: str, figures: dict) -> str:
    """One line: what :func:`choose_space_use` (``name`` 'field'),
    :func:`choose_herd_place` ('place') or :func:`choose_noise_regimes` ('noise') kept
    (from its figures), and why."""
    field = name == 'field'
    name, plain, extra = {'field': ('field', 'fitted', 'space-use'),
                          'place': ('herd place', 'none', 'each agent\'s'),
                          'noise': ('noise', 'gaussian', 'regimes')}[name]
    if 'reason' in figures:
        return f'{name}: {plain} ({figures["reason"]})'
    kept = extra if figures.get('kept') else plain
    if field:
        f, s = figures['fitted'], figures['space_use']
        errors = (s['free_run_error'], f['free_run_error'])
        why = (f'free-run error {_error(s["free_run_error"])} with space-use vs '
               f'{_error(f["free_run_error"])} fitted, one-step RMS {s["one_step"]:.4f} vs '
               f'{f["one_step"]:.4f}')
    elif name == 'herd place':
        w, p = figures['without'], figures['with']
        errors = (p['free_run_error'], w['free_run_error'])
        why = (f'free-run error {_error(p["free_run_error"])} with the places vs '
               f'{_error(w["free_run_error"])} without, one-step RMS {p["one_step"]:.4f} vs '
               f'{w["one_step"]:.4f}')
    else:
        r, g = figures['regimes'], figures['gaussian']
        errors = (r['free_run_error'], g['free_run_error'], r['shape_error'], g['shape_error'])
        why = (f'free-run error with {figures["regimes_count"]} regimes vs gaussian: all '
               f'statistics {_error(r["free_run_error"])} vs {_error(g["free_run_error"])}, '
               f'shape {_error(r["shape_error"])} vs {_error(g["shape_error"])}')
    if not np.isfinite(errors).all():
        why += ('; n/a: a statistic of the run or the tail is zero or undefined there, '
                'so the error has no value')
    return f'{name}: {kept} (validation tail of the training data: {why})'
