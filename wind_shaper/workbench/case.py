"""The case under diagnosis: the one record that goes down the diagnosis's stages.

``open_case`` (the first stage) splits the sweeps, refits the model on the training sweeps and
measures the noise, the command spread and the clocks; each later stage takes the ``Case`` and
returns it with its own part filled in:

0. ``time_checks.check_time``: does the residual depend on when a force was recorded
   (``time``; ``held`` when a fault stops the naming of effects);
1. ``selection.select``: screen and select candidates (``steps``, ``rankings``);
2. ``checks.check_findings``: every registered check of each finding (``steps`` keeps what
   passed, ``demoted`` the rest, ``final`` the model with the findings);
3. ``rest.describe_rest``: what the findings leave (``discrepancy``, ``formula``, ``undecided``);
4. ``verdict.word``: the verdict (``verdict``; the words are written from the case on demand).

``settings`` is the ``Diagnosis`` that holds the settings (its constructor arguments); no stage
calls back into it. Forces [N].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import TunnelGeometry
from ..model import Term
from .data import FitData, SweepSet
from .errors import FitError
from .fitting import FitResult, fit_model
from .library import Library, apply_candidate, default_library
from .metrics import HeldOut
from .noise_floor import NoiseFloor, noise_floor_test
from .sync import check_sync
from .trial import fit_mask

__all__ = ['Case', 'open_case', 'MIN_SWEEPS']

#: Fewer sweeps leave too few held out (every third) to judge a finding.
MIN_SWEEPS = 6


@dataclass
class Case:
    """The data, the settings and what each stage found (see the module docstring).

    geometry; library; model: the model as given; command_spread, low_spread: the sweeps'
    command spread and whether it is too low to report findings; train_sweeps, test_sweeps:
    the split; train, screen: the training cells (all, every second); heldout, heldout_off: the
    held-out sweeps (all; fans off and on, or None); baseline: the refit of ``model``;
    noise_sd [N]; baseline_rmse, baseline_raw [N]: its held-out model and raw errors; sync: the
    clocks' check (or None); noise_floor: the baseline's held-out residual tested against the
    noise (``noise_floor``), final_floor: the same for the model with the findings."""

    settings: object
    geometry: TunnelGeometry
    library: Library
    model: Term
    command_spread: dict
    low_spread: bool
    train_sweeps: SweepSet
    test_sweeps: SweepSet
    train: FitData
    screen: FitData
    heldout: HeldOut
    heldout_off: tuple | None
    baseline: FitResult
    noise_sd: float
    baseline_rmse: float
    baseline_raw: float
    sync: object = None
    noise_floor: NoiseFloor | None = None
    #: the sweeps as given, in recording order (the time checks read them whole)
    data: SweepSet | None = None
    # time checks (``time_checks.check_time``): {name: TimeResult}; held: a fault in time
    # stops the stages that would name effects
    time: dict = field(default_factory=dict)
    held: bool = False
    # selection
    steps: list = field(default_factory=list)
    rankings: list = field(default_factory=list)
    selected: list = field(default_factory=list)
    current: FitResult | None = None
    current_rmse: float = float('nan')
    # checks of the findings
    demoted: list = field(default_factory=list)
    final: FitResult | None = None
    final_rmse: float = float('nan')
    final_raw: float = float('nan')
    final_floor: NoiseFloor | None = None
    # what is left
    discrepancy: object = None
    formula: object = None
    undecided: object = None
    # the verdict
    verdict: str = ''

    def evaluate(self, model: Term) -> tuple[float, float]:
        """The held-out (model error, raw error) of ``model`` [N]."""
        ev = self.heldout.evaluate(model)
        return ev['model_rmse'], ev['raw'].rmse

    def floor_test(self, model: Term) -> NoiseFloor:
        """``model``'s held-out residual tested against the noise (``noise_floor``): the
        noise's own uncertainty counts when it was estimated from the sweeps, not when given."""
        d = self.heldout.data
        given = self.settings.noise_sd is not None
        return noise_floor_test(d.y - model(d.U, d.Z), d.sweep, self.noise_sd,
                                resolution=float('nan') if given else self.heldout.resolution)

    def rebuild(self, steps: list) -> FitResult:
        """The baseline model with the effects of ``steps`` added, refitted on the training
        sweeps."""
        model = self.baseline.model
        for t in steps:
            model = apply_candidate(model, t.candidate, **t.params)
        if not steps:
            return self.baseline
        return fit_model(model, self.train, free=fit_mask(model), max_nfev=15)


def _fans_off_split(test_sweeps: SweepSet, geometry: TunnelGeometry):
    """(held-out fans-off sweeps, the other held-out sweeps) as ``HeldOut`` sets, each with
    its own noise (turbulence grows with the thrust), or None when no held-out sweep has
    every fan off."""
    commands = test_sweeps.commands[:, geometry.fans.enabled]
    off = [i for i, u in enumerate(commands) if np.all(np.abs(u) < 1e-6)]
    on = [i for i in range(len(commands)) if i not in off]
    if not off or not on:
        return None
    return HeldOut(test_sweeps[off]), HeldOut(test_sweeps[on])


def open_case(settings, model: Term, data: SweepSet, geometry: TunnelGeometry) -> Case:
    """The first stage: check the data against the tunnel, split the sweeps (by sweep), refit
    ``model``'s free parameters on the training sweeps (``fit_mask``) and measure the noise,
    the command spread and the clocks. ``settings``: the ``Diagnosis``."""
    s = settings
    data.check_fans(geometry.fans.names)
    if len(data) < MIN_SWEEPS:
        raise FitError(f'{len(data)} sweeps are too few for a diagnosis: it holds every third '
                       f'sweep out to judge the findings and needs at least {MIN_SWEEPS} (8-12 '
                       f'are better); record more at varied commands, e.g. `wind-shaper collect '
                       f'--design lhs:12 --out NAME`, and pool them with --data')
    if model.n_fans != geometry.fans.n_fans:
        raise FitError(f'the model is for {model.n_fans} fans, the tunnel has {geometry.fans.n_fans}')
    library = s.library or default_library()
    spread = data.command_spread(geometry.fans.enabled)
    train_sweeps, test_sweeps = data.split(s.test_fraction, s.test)
    train = train_sweeps.fit_data(s.cell)
    heldout = HeldOut(test_sweeps)
    heldout_off = _fans_off_split(test_sweeps, geometry)
    base = fit_model(model, train, free=fit_mask(model), max_nfev=s.max_nfev)
    noise_sd = float(s.noise_sd) if s.noise_sd is not None else heldout.estimate_noise(base.model)
    if not np.isfinite(noise_sd):
        raise FitError('the held-out sweeps revisit too few places to estimate the measurement '
                       'noise: record sweeps of 1000 samples (the default tour crosses the disc more '
                       'than once) or give the noise per sample (noise_sd, --noise-sd)')
    heldout.noise_sd = noise_sd
    ev = heldout.evaluate(base.model)
    case = Case(settings=s, geometry=geometry, library=library, model=model,
                command_spread=spread, low_spread=spread['median'] < s.min_spread,
                train_sweeps=train_sweeps, test_sweeps=test_sweeps, train=train,
                screen=train.subset(slice(None, None, 2)),  # screening needs only a ranking
                heldout=heldout, heldout_off=heldout_off, baseline=base, noise_sd=noise_sd,
                baseline_rmse=ev['model_rmse'], baseline_raw=ev['raw'].rmse,
                sync=check_sync(base.model, data) if s.check_clocks else None, data=data)
    case.noise_floor = case.floor_test(base.model)
    return case
