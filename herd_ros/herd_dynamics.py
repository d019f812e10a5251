"""One object for a herd's learned dynamics: fit, learn online, predict, simulate, score,
save and load (the model surface of issue 26, in the manner of PySINDy's ``SINDy``
estimator).

:class:`HerdDynamics` wraps a model of any kind (:mod:`herd_ros.model.kinds`: the paper's
pairwise law or the shared law) and the two ways of learning it:

* :meth:`HerdDynamics.fit` — batch: blocked cross-validation of the structure
  (:func:`~herd_ros.estimation.model_selection.select_model`), least squares of the chosen
  structure (:func:`~herd_ros.estimation.herd_fit.fit_structure`, eqs. 6–8 of Schwager,
  Anderson & Rus 2007), then the long-run terms a free run needs (the space-use field, each
  agent's place in the herd and the noise regimes, each kept only when a validation tail of
  the training data says so:
  :mod:`herd_ros.estimation.field_choice`);
* :meth:`HerdDynamics.partial_fit` — recursive least squares one snapshot at a time
  (:class:`~herd_ros.estimation.online_fit.OnlineHerdEstimator`, the ``estimator`` node's
  core).

and what is done with it: :meth:`predict` (k steps ahead with the covariance, eq. 8
iterated), :meth:`simulate` (eq. 2 with noise), :meth:`score` (one-step RMS beside the naive
baselines, and the free-run statistics of issue 30), :attr:`coefficients` and
:attr:`parameter_names` (θ_i per agent, in the model file's order), :meth:`save` and
:meth:`load`. The command line's ``fit``, ``predict``, ``simulate`` and ``report``, the
estimator and the controller go through it.

Plain numpy; no ROS::

    from herd_ros.herd_dynamics import HerdDynamics
    from herd_ros.trajectory import read_trajectory_csv
    runs = read_trajectory_csv('herd.csv')
    dyn = HerdDynamics().fit(runs)
    print(dyn.score(runs)['one_step_rms']['model']['herd'])
    dyn.save('model.yaml')
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.estimation.model_selection import FOLDS, MEMORIES, RIDGES
from herd_ros.model.rbf_field import DEFAULT_MIN_VISITS

FIELDS = ('auto', 'fitted', 'space-use')
NOISES = ('auto', 'gaussian', 'regimes')
ALIGNMENTS = ('auto', 'off', 'on')


@dataclass
class FitOptions:
    """How :meth:`HerdDynamics.fit` learns (the options of ``herd-ros fit``).

    Attributes:
        terms: candidate term sets (None = every one of
            :data:`~herd_ros.estimation.model_selection.TERMS`).
        grids: candidate field grids (nx, ny) (None = chosen among the defaults).
        bounds: field bounds (xmin, xmax, ymin, ymax) (None = the visited region).
        ridges: candidate ridge λ (cross-validated).
        memory: the velocity memory κ of every candidate; ``memories``: others tried last.
        law: 'pairwise', 'shared' or None (by herd size).
        own_agents: distinguished agents with their own profile; None = screened for.
        field: 'auto', 'fitted' or 'space-use'; ``noise``: 'auto', 'gaussian', 'regimes'.
        robust: outlier-robust IRLS; ``se``: 'sandwich' or 'ols' standard errors.
        folds: cross-validation blocks per run; ``min_visits``: samples a field centre needs.
        noise_scale: ``'auto'``: each animal's free-run noise calibrated to keep its pace on
            the training data (:mod:`herd_ros.simulation.pace_calibration`); a positive
            number: that factor on every animal's noise std (1 = the residuals' noise, the
            paper's).
        place: each agent's place in the herd (:mod:`herd_ros.model.herd_place`):
            'auto' (kept when the validation tail's free run says so), 'on' or 'off'.
        alignment: velocity alignment (:mod:`herd_ros.model.alignment`): 'auto' (tried on
            the chosen structure, kept if cross-validation does), 'off' or 'on' (the
            structure chosen among the cross-validated candidates with alignment);
            ``alignment_neighbourhood`` 'radius' or 'nearest' (``alignment_nearest`` = k).
    """

    terms: list | None = None
    grids: list | None = None
    bounds: tuple | None = None
    ridges: tuple = RIDGES
    memory: float = 1.0
    memories: tuple = MEMORIES
    law: str | None = None
    own_agents: list | None = None
    field: str = 'auto'
    noise: str = 'auto'
    robust: bool = False
    se: str = 'sandwich'
    folds: int = FOLDS
    min_visits: int = DEFAULT_MIN_VISITS
    noise_scale: str | float = 'auto'
    place: str = 'auto'
    alignment: str = 'auto'
    alignment_neighbourhood: str = 'radius'
    alignment_nearest: int = 7

    def __post_init__(self):
        if self.alignment not in ALIGNMENTS:
            raise HerdInputError(f'alignment must be one of {ALIGNMENTS}, got '
                                 f'{self.alignment!r}')
        if self.field not in FIELDS:
            raise HerdInputError(f'field must be one of {FIELDS}, got {self.field!r}')
        if self.noise not in NOISES:
            raise HerdInputError(f'noise must be one of {NOISES}, got {self.noise!r}')
        if self.noise_scale != 'auto':
            try:
                value = float(self.noise_scale)
            except (TypeError, ValueError):
                value = float('nan')
            if not (np.isfinite(value) and value > 0):
                raise HerdInputError(f"noise_scale must be 'auto' or a positive number, got "
                                     f'{self.noise_scale!r}')
            self.noise_scale = value
        if self.folds < 2:
            raise HerdInputError(f'folds must be at least 2, got {self.folds}')


class _Silent:
    """A progress bar that shows nothing."""

    def update(self, n=1):
        pass

    def close(self):
        pass


def _silent_progress(total=None, desc='', unit='it'):
    return _Silent()


def _runs_list(runs) -> list:
    from herd_ros.trajectory import HerdTrajectory
    return [runs] if isinstance(runs, HerdTrajectory) else list(runs)


@dataclass
class HerdDynamics:
    """A herd's learned dynamics (module docstring).

    Attributes:
        model: the model (None before a fit): a
            :class:`~herd_ros.model.herd_model.HerdModel` or
            :class:`~herd_ros.model.shared_law.SharedLawModel`.
        options: the batch fit's :class:`FitOptions`.
        selection: after :meth:`fit`, the cross-validation
            (:class:`~herd_ros.estimation.model_selection.Selection`).
        choices: after :meth:`fit`, what was chosen and why (the model file's
            ``selection`` mapping).
        fit_result: after :meth:`fit`, the per-agent least-squares results
            (:class:`~herd_ros.estimation.herd_fit.HerdFit`).
        online: the recursive estimator behind :meth:`partial_fit` (None until
            :meth:`online_learner` makes one).
    """

    model: object = None
    options: FitOptions = field(default_factory=FitOptions)
    selection: object = None
    choices: dict = field(default_factory=dict)
    fit_result: object = None
    online: object = None

    # -- learning --------------------------------------------------------------------------
    def fit(self, runs, *, datum=None, seed: int = 0, progress=None, log=None) -> HerdDynamics:
        """Learn the model from ``runs`` (a :class:`~herd_ros.trajectory.HerdTrajectory` or
        a list on one clock): the structure by blocked cross-validation, θ by least squares,
        the long-run terms by a validation tail (module docstring).

        Args:
            datum: the WGS84 datum of the runs' frame, kept in the model.
            seed: seed of the validation simulations.
            progress: ``progress(total=, desc=, unit=)`` -> a bar with ``update`` and
                ``close`` (default: none).
            log: a callable taking one line of text (default: silent).
        """
        from herd_ros.estimation.herd_fit import aligned_positions, check_runs, fit_structure
        from herd_ros.estimation.model_selection import (PAIRWISE_MAX_AGENTS,
                                                         default_alignment, select_model)
        runs = _runs_list(runs)
        agents, dt = check_runs(runs)
        o = self.options
        progress = progress or _silent_progress
        # a shared-law herd may get a second pass (a nominated driver): count, no fixed total
        bar = progress(total=None if len(agents) > PAIRWISE_MAX_AGENTS or o.own_agents else
                       len(agents) * (1 + bool(o.memories)),
                       desc='cross-validating', unit='agent')
        positions = [aligned_positions(r, agents) for r in runs]
        kernel = None
        if o.alignment != 'off':
            kernel = replace(default_alignment(positions),
                             neighbourhood=o.alignment_neighbourhood,
                             nearest=int(o.alignment_nearest))
        sel = select_model(positions, agents, dt,
                           folds=o.folds, ridges=o.ridges, grids=o.grids, terms=o.terms,
                           bounds=o.bounds, min_visits=o.min_visits, law=o.law,
                           own_agents=o.own_agents, progress=lambda a: bar.update(1),
                           memory=o.memory, memories=o.memories,
                           # auto: tried unless --terms pinned the structure
                           alignment=kernel if o.terms is None or o.alignment == 'on'
                           else None,
                           # 'on': chosen among the alignment candidates (cross-validated,
                           # so the table and the report have the chosen one's CV error)
                           alignment_required=o.alignment == 'on')
        bar.close()
        bar = progress(total=len(agents), desc='fitting agents', unit='agent')

        def refit(train):
            return fit_structure(train, sel.chosen, law=sel.law, profile=sel.profile,
                                 bounds=sel.bounds, min_visits=o.min_visits, se=o.se,
                                 datum=datum, robust=o.robust, own_agents=sel.own_agents,
                                 own_profile=sel.own_profile, progress=lambda a: bar.update(1))
        result = refit(runs)
        bar.close()
        self.selection = sel
        self.choices = sel.as_dict()
        self.choices['loss'] = 'robust' if o.robust else 'l2'
        model = self._long_run_terms(result.model, runs, refit, progress, log or (lambda s: None))
        self.fit_result = dataclasses.replace(result, model=model) \
            if model is not result.model else result
        self.model = self.fit_result.model
        return self

    def _long_run_terms(self, model, runs, refit, progress, log):
        """The space-use field, the herd places and the noise regimes of the options
        (``auto``: each kept when the validation tail of the training data says so);
        recorded in :attr:`choices`."""
        from herd_ros.estimation.herd_fit import aligned_positions
        o, chosen = self.options, self.choices
        positions = [aligned_positions(r, model.agents) for r in runs]
        field_opt, noise = o.field, o.noise
        check = None
        if 'auto' in (field_opt, noise, o.place):
            from herd_ros.estimation.field_choice import ValidationTail
            # one validation tail for the three checks: the chosen structure refitted once
            check = ValidationTail(runs, lambda train: refit(train).model)
        if field_opt == 'auto':
            from herd_ros.estimation.field_choice import choose_space_use, describe_choice
            keep, chosen['field_choice'] = choose_space_use(check)
            field_opt = 'space-use' if keep else 'fitted'
            log(describe_choice('field', chosen['field_choice']))
        if field_opt == 'space-use':
            from herd_ros.model.space_use_field import with_space_use_field
            bar = progress(total=model.n_agents, desc='space-use field', unit='agent')
            model = with_space_use_field(model, np.concatenate(positions),
                                         progress=lambda n: bar.update(n))
            bar.close()
            chosen['field'] = 'space-use'
            h = model.meta['space_use_bandwidth']
            if np.isfinite(h).any():
                log(f'space-use field: kernel bandwidth {np.nanmin(h):.2f}-'
                    f'{np.nanmax(h):.2f} m')
            for agent, why in model.meta['space_use_kept_fitted'].items():
                log(f'space-use field: {agent} keeps its fitted field ({why})')
        place = o.place
        if place == 'auto':
            from herd_ros.estimation.field_choice import choose_herd_place, describe_choice
            keep, chosen['place_choice'] = choose_herd_place(
                check, space_use=field_opt == 'space-use')
            place = 'on' if keep else 'off'
            log(describe_choice('place', chosen['place_choice']))
        if place == 'on':
            from herd_ros.model.herd_place import with_herd_place
            model = with_herd_place(model, np.concatenate(positions))
        chosen['herd_place'] = (model.meta or {}).get('herd_place') is not None
        if noise == 'auto':
            from herd_ros.estimation.field_choice import choose_noise_regimes, describe_choice
            keep, chosen['noise_choice'] = choose_noise_regimes(
                check, space_use=field_opt == 'space-use', place=chosen['herd_place'])
            noise = 'regimes' if keep else 'gaussian'
            log(describe_choice('noise', chosen['noise_choice']))
        if noise == 'regimes':
            from herd_ros.model.noise_regimes import with_noise_regimes
            log('noise regimes: fitting 1-3 regimes per agent (Baum-Welch) ...')
            model, regimes = with_noise_regimes(model, positions)
            chosen['noise_regimes'] = regimes['n_regimes']
            log(f'noise regimes: BIC keeps {regimes["n_regimes"]} (' + ', '.join(
                f'K={k}: {v:.0f}' for k, v in sorted(regimes['bic'].items())) + ')')
            if regimes['n_regimes'] > 1 and regimes['too_few']:
                log('noise regimes: too few residuals, Gaussian noise kept for ' + ', '.join(
                    model.agents[i] for i in regimes['too_few']))
        from herd_ros.simulation.pace_calibration import (calibrate_noise_scale,
                                                          describe_calibration,
                                                          with_noise_scale)
        if o.noise_scale == 'auto':
            log('noise scale: calibrating each animal\'s free-run noise to its pace ...')
            cal = calibrate_noise_scale(model, positions)
            model = with_noise_scale(model, cal['scale'])
            chosen['noise_scale'] = {
                'method': 'pace', 'iterations': cal['iterations'],
                'segments': cal['segments'],
                'scale': [float(x) for x in cal['scale']],
                'data_pace': [float(x) for x in cal['data_pace']],
                'uncalibrated_pace': [float(x) for x in cal['uncalibrated_pace']],
                'pace': [float(x) for x in cal['sim_pace']]}
            log(describe_calibration(cal, model.agents))
        elif o.noise_scale != 1.0:
            model = with_noise_scale(model, np.full(model.n_agents, float(o.noise_scale)))
            chosen['noise_scale'] = {'method': 'given', 'scale': float(o.noise_scale)}
        if chosen['herd_place'] and 'noise_scale' in (model.meta or {}):
            # the places' gains for the noise the law now draws (P1: K_i ∝ Q_i)
            from herd_ros.model.herd_place import with_herd_place
            model = with_herd_place(model, np.concatenate(positions))
        return model

    @classmethod
    def online_learner(cls, agents, dt: float, **kwargs) -> HerdDynamics:
        """Dynamics learned one snapshot at a time by recursive least squares
        (:class:`~herd_ros.estimation.online_fit.OnlineHerdEstimator`; ``kwargs`` are its
        options: law, field_grid, field_bounds, forgetting, ...)."""
        from herd_ros.estimation.online_fit import OnlineHerdEstimator
        return cls(online=OnlineHerdEstimator(agents, dt, **kwargs))

    def partial_fit(self, time: float, positions):
        """One snapshot (every agent's position at ``time``, (N, 2), NaN = missing) into the
        recursive least squares; returns its
        :class:`~herd_ros.estimation.online_fit.SnapshotResult`. :attr:`model` is then the
        current estimate (read it when needed: it is built on access)."""
        if self.online is None:
            raise HerdInputError('partial_fit needs an online learner: '
                                 'HerdDynamics.online_learner(agents, dt, ...)')
        self.model = None
        return self.online.add_snapshot(float(time), np.asarray(positions, dtype=float))

    @property
    def current(self):
        """The model: the batch fit's, the loaded one, or the online estimate now."""
        if self.model is None and self.online is not None:
            return self.online.model()
        if self.model is None:
            raise HerdInputError('no model yet: fit, load or learn online first')
        return self.model

    # -- using it --------------------------------------------------------------------------
    def predict(self, positions, steps: int = 1, return_cov: bool = False):
        """k-step-ahead positions at every step of a run (positions (T, N, 2) in the model's
        agent order; eq. 8 iterated, :func:`~herd_ros.simulation.prediction.predict_ahead`);
        with ``return_cov`` also their covariance (T, N, 2, 2): the model's k-step
        covariance scaled by each agent's running noise level up to the origin."""
        from herd_ros.simulation.prediction import (noise_level, predict_ahead,
                                                    prediction_covariance)
        model = self.current
        p = np.asarray(positions, dtype=float)
        pred = predict_ahead(model, p, steps)
        if not return_cov:
            return pred
        cov = prediction_covariance(model, steps)                        # (N, 2, 2)
        level = noise_level(model, p, steps)                             # (T, N)
        return pred, level[..., None, None] * cov[None]

    def simulate(self, initial_positions, steps: int, initial_velocities=None, seed=None,
                 noise: bool = True, t0: float = 0.0, progress=None):
        """The law run freely for ``steps`` steps from p⁰ (and u⁰) (eq. 2 with noise, or
        without): a :class:`~herd_ros.trajectory.HerdTrajectory`."""
        from herd_ros.simulation.herd_simulator import simulate
        return simulate(self.current, steps, initial_positions, initial_velocities, seed=seed,
                        noise=noise, t0=t0, progress=progress)

    def score(self, runs, train=None, seed: int = 0) -> dict:
        """Every figure of the fit report on ``runs`` (``train``: the data the model was
        fitted on, for the damping-only baseline; default ``runs``): one-step and k-step
        RMS beside constant velocity, stay-put, damping-only and (GPS input) the last raw
        fix; whiteness; simulated statistics; the free-run fidelity of issue 30
        (:func:`~herd_ros.estimation.validation.validate`)."""
        from herd_ros.estimation.validation import validate
        runs = _runs_list(runs)
        train = runs if train is None else _runs_list(train)
        return validate(self.report_fit(runs), train, runs, seed=seed)

    def report_fit(self, runs):
        """The :class:`~herd_ros.estimation.herd_fit.HerdFit` the report's figures read: the
        batch fit's, or the model alone with its field drawn over ``runs``' region."""
        from herd_ros.estimation.herd_fit import HerdFit
        from herd_ros.model.rbf_field import FieldGrid
        if self.fit_result is not None and self.fit_result.model is self.model:
            return self.fit_result
        pts = np.concatenate([r.positions.reshape(-1, 2) for r in _runs_list(runs)])
        return HerdFit(self.current, {}, FieldGrid.over(pts[np.isfinite(pts).all(-1)], 8, 8))

    # -- parameters ------------------------------------------------------------------------
    @property
    def coefficients(self) -> dict:
        """θ_i of every agent ({agent: (p_i,)}), in the model file's order."""
        model = self.current
        if hasattr(model, 'laws'):
            return {a: model.laws[a].theta for a in model.agents}
        return {a: model.theta(i) for i, a in enumerate(model.agents)}

    @property
    def parameter_names(self) -> dict:
        """The names of θ_i's entries ({agent: [name, ...]}), as :attr:`coefficients`."""
        model = self.current
        if hasattr(model, 'laws'):
            return {a: model.laws[a].parameter_names for a in model.agents}
        return {a: model.parameter_names(i) for i, a in enumerate(model.agents)}

    # -- files and messages ----------------------------------------------------------------
    def save(self, path):
        """Write the model file of the model's kind (with the selection, after a fit)."""
        from herd_ros.model import kinds
        from herd_ros.model.model_file import selection_entry
        return kinds.save(self.current, path,
                          selection=selection_entry(self.choices) if self.choices else None)

    @classmethod
    def load(cls, path) -> HerdDynamics:
        """The dynamics of a model file of any kind."""
        from herd_ros.model import kinds
        return cls(model=kinds.load(path))

    @classmethod
    def from_dict(cls, body: dict, source: str = 'model') -> HerdDynamics:
        """The dynamics of a ``model:`` mapping of any kind (a node's ``model.*``)."""
        from herd_ros.model import kinds
        return cls(model=kinds.from_dict(body, source))

    @classmethod
    def from_parameters(cls, theta, structure, noise_cov=None) -> HerdDynamics:
        """The dynamics of a published θ matrix (N × p, ``/herd/model/params``) read with
        its :class:`~herd_ros.model.model_structure.ModelStructure`
        (``/herd/model/structure``) and Q_i (``/herd/model/noise``, zero if None)."""
        from herd_ros.control.herd_follower import (model_from_parameter_matrix,
                                                    shared_model_from_parameter_matrix)
        from herd_ros.model.rbf_field import FieldGrid
        from herd_ros.model.alignment import VelocityAlignment
        st = structure
        grid = FieldGrid(*st.field_grid, tuple(st.field_bounds))
        theta = np.asarray(theta, dtype=float)
        B = st.alignment_size
        law = theta[:, :theta.shape[1] - B]
        if st.law == 'shared':
            model = shared_model_from_parameter_matrix(
                law, list(st.agents), st.dt, grid, st.interaction_radius, st.profile_size,
                noise_cov)
        else:
            model = model_from_parameter_matrix(law, list(st.agents), st.dt, grid, noise_cov)
        if B:
            model.alignment = VelocityAlignment(st.alignment_kernel(), theta[:, -B:])
        return cls(model=model)
