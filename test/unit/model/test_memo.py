"""The model's geometry cache (wind_shaper.model.memo): only read-only points take part, a result
comes back for equal keys only, memory stays bounded, and a model evaluated through the cache
gives exactly what it gives without it."""
import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.model import FanGain, Sum, memo, set_fixed, walk, wrap
from wind_shaper.workbench.library import apply_candidate, default_library


@pytest.fixture(autouse=True)
def fresh_cache():
    memo.clear()
    yield
    memo.clear()


def _counting(value):
    calls = []

    def compute():
        calls.append(1)
        return np.array(value, dtype=float)
    return compute, calls


def test_read_only_points_are_remembered_by_identity_and_key():
    points = memo.freeze(np.random.default_rng(0).normal(size=(50, 2)))
    compute, calls = _counting([1.0, 2.0])
    first = memo.remember(points, ('k', 1.0), compute)
    again = memo.remember(points, ('k', 1.0), compute)
    assert again is first and len(calls) == 1
    assert not first.flags.writeable  # nobody downstream can change what others will reuse
    memo.remember(points, ('k', 2.0), compute)  # another parameter value: computed again
    memo.remember(memo.freeze(points.copy()), ('k', 1.0), compute)  # equal values, other array
    assert len(calls) == 3


def test_writable_points_are_never_remembered():
    points = np.zeros((10, 2))
    compute, calls = _counting([0.0])
    memo.remember(points, 'k', compute)
    points[0] = 1.0  # a caller may change its own buffer between calls
    memo.remember(points, 'k', compute)
    assert len(calls) == 2
    # nor is a read-only view of a writable array
    view = points[:5]
    view.flags.writeable = False
    memo.remember(view, 'k', compute)
    memo.remember(view, 'k', compute)
    assert len(calls) == 4


def test_freeze_copies_a_writable_array_and_keeps_a_frozen_one():
    a = np.arange(6.0).reshape(3, 2)
    frozen = memo.freeze(a)
    assert frozen is not a and a.flags.writeable and not frozen.flags.writeable
    assert memo.freeze(frozen) is frozen
    with pytest.raises(ValueError):
        frozen[0, 0] = 1.0


def test_memory_stays_bounded(monkeypatch):
    monkeypatch.setattr(memo, 'MAX_BYTES', 10 * 8000)
    points = memo.freeze(np.zeros((1000, 2)))
    for k in range(50):
        memo.remember(points, k, lambda: np.zeros(1000))  # 8000 bytes each
    assert memo._bytes <= 10 * 8000 and len(memo._entries) == 10
    compute, calls = _counting(np.zeros(1000))
    memo.remember(points, 49, compute)  # the newest entries stay
    memo.remember(points, 0, compute)  # the oldest went
    assert len(calls) == 1


def test_a_model_gives_the_same_numbers_with_and_without_the_cache():
    setup = Setup.load()
    reference = setup.load_model(setup.config_dir / 'reference.yaml')
    rng = np.random.default_rng(3)
    Z = rng.uniform(-0.4, 0.4, size=(400, 2))
    U = rng.uniform(0.2, 0.9, size=(400, reference.n_fans))
    Uf, Zf = memo.freeze(U), memo.freeze(Z)
    cands = {c.name: c for c in default_library().candidates(reference, setup.geometry)}
    models = {name: apply_candidate(reference, cands[name])
              for name in ('fan_shift[HM2]', 'fan_width[higher]', 'fan_elongation[LM2]',
                           'jet_interaction', 'wall_layer', 'swirl', 'dead_band')}
    prior = next(t for t in walk(reference) if isinstance(t, Sum))  # jets and ring, unwrapped
    models['one fan of the bare prior'] = wrap(FanGain, prior, fan='HM2')
    for name, model in models.items():
        # every parameter free, and versions that differ from one another in one parameter
        # only: a key that misses it would hand one version's geometry to the other
        model = set_fixed(model, False)
        lo, hi = model.bounds.T
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        # off the start values, which are often "no effect" (a strength of 0 hides its shape)
        base = np.clip(model.theta + 0.05 * span * rng.uniform(0.2, 1, len(lo)), lo, hi)
        first = model.with_theta(base)
        first.value_and_jacobian(Uf, Zf)
        for i in range(len(base)):
            theta = base.copy()
            theta[i] = np.clip(theta[i] - 0.01 * span[i], lo[i], hi[i])
            moved = model.with_theta(theta)
            plain_v, plain_j = moved.value_and_jacobian(U.copy(), Z.copy())
            v, j = moved.value_and_jacobian(Uf, Zf)
            np.testing.assert_array_equal(v, plain_v, err_msg=f'{name}: {model.theta_names[i]}')
            np.testing.assert_array_equal(j, plain_j, err_msg=f'{name}: {model.theta_names[i]}')
    assert memo._entries  # the frozen evaluations did use it
