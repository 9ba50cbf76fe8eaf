"""Candidate effect terms: one registry test runs every kind through the same checks (analytic
Jacobian vs finite differences, theta and model-file round trips, no effect at the null values,
fan parts adding up), then each hypothesis's own law."""
import numpy as np
import pytest

from wind_shaper import model as E
from wind_shaper.core.errors import ConfigError
from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.model import (TERMS, CentralRing, FanJets, finite_difference_jacobian,
                               term_from_dict)
from wind_shaper.model.footprint_effects import plate_stretch_share


@pytest.fixture(scope='module')
def rig():
    return TunnelGeometry.paper_rig()


@pytest.fixture(scope='module')
def base(rig):
    jets = FanJets(rig.fans, thrust_higher=(0.1, 2.5, 11.0), thrust_lower=(0.05, 2.0, 8.0), sigma=0.14)
    return jets + CentralRing(rig.fans, thrust=(0.0, 3.0, 7.0), offset=0.2, sigma=0.25)


def _instances(fans, base):
    """Every library kind at non-null values, plus nestings the workbench builds."""
    return {
        'fan_gain': E.FanGain(fans, base, fan='HM2', gain=0.8),
        'fan_gain_groups': E.FanGain(fans, base, group=['higher', 'central'], gain=[0.9, 1.2]),
        'fan_shift': E.FanShift(fans, base, fan=['LM2', 'CM'], shift=[[0.03, 0.01], [0.0, -0.02]]),
        'fan_push': E.FanPush(fans, base, fan=['HM1', 'LM2'], push=[0.03, -0.02]),
        'fan_push_groups': E.FanPush(fans, base, group=E.ALL_FANS, push=0.025),
        'fan_width': E.FanWidth(fans, base, fan='LM1', scale=1.2),
        'fan_elongation': E.FanElongation(fans, base, fan='LM2', ratio=1.6, angle=0.3),
        'fan_curve': E.FanCurve(fans, base, group=['higher', 'lower', 'central'], bend=[0.4, 0.3, 1.0]),
        'fan_shape': E.FanShape(fans, base, group=['higher', 'lower'], flatness=[2.3, 2.1]),
        'swirl': E.Swirl(fans, base, gain=0.5),
        'swirl_quadratic': E.SwirlQuadratic(fans, base, gain=0.3, curvature=0.8),
        'jet_interaction': E.JetInteraction(fans, base, strength=0.3, width=1.1),
        'jet_interaction_mean': E.JetInteraction(fans, base, strength=0.3, width=1.1, follows='mean'),
        'jet_interaction_power': E.JetInteractionPower(fans, base, strength=0.3, width=1.1, exponent=0.7),
        'dead_band': E.DeadBand(fans, base, threshold=0.12, saturation=0.75),
        'wall_layer': E.WallLayer(fans, base, thickness=0.06),
        'background': base + E.Background(fans, force=0.3),
        'nested': E.Swirl(fans, E.FanGain(fans, E.JetInteraction(fans, E.DeadBand(
            fans, E.FanShift(fans, E.WallLayer(fans, base, 0.05), shift=np.full(14, 0.01)),
            threshold=0.1, saturation=0.8), strength=0.2), fan='HM1', gain=0.7), gain=0.3)
            + E.Background(fans, 0.2),
        'gain_of_swirl': E.FanGain(fans, E.Swirl(fans, base, gain=0.4), fan='HM2', gain=0.8),
    }


NAMES = list(_instances(TunnelGeometry.paper_rig().fans, FanJets(TunnelGeometry.paper_rig().fans)))


def test_every_library_kind_is_registered_and_covered():
    library_kinds = {'fan_gain', 'fan_shift', 'fan_width', 'fan_elongation', 'fan_curve', 'fan_shape',
                     'swirl', 'swirl_quadratic', 'jet_interaction', 'jet_interaction_power', 'dead_band',
                     'wall_layer', 'background'}
    assert library_kinds <= set(TERMS)
    assert library_kinds <= {n.replace('_groups', '') for n in NAMES}


@pytest.mark.parametrize('name', NAMES)
def test_registry_jacobian_round_trips_and_parts(rig, base, name, rng):
    term = _instances(rig.fans, base)[name]
    pts = rig.key_points[::3]
    for _ in range(2):
        U = rng.uniform(0.05, 0.8, 7)
        np.testing.assert_allclose(term.jacobian(U, pts), finite_difference_jacobian(term, U, pts),
                                   rtol=1e-5, atol=2e-6)
    assert len(term.theta) == len(term.theta_names) == len(term.bounds)
    np.testing.assert_allclose(term.with_theta(term.theta)(U, pts), term(U, pts))
    bumped = term.with_theta(np.clip(term.theta * 1.02, *term.bounds.T))
    assert not np.allclose(bumped(U, pts), term(U, pts))
    rebuilt = term_from_dict(term.to_dict(), rig.fans)  # the model-file form
    np.testing.assert_allclose(rebuilt(U, pts), term(U, pts))
    assert repr(rebuilt) == repr(term)
    if E.is_fan_sum(term):  # the parts add up to the whole
        Ub = rng.uniform(0.05, 0.8, (len(pts), 7))
        total = sum(E.fan_part(term, Ub, pts, j)[0] for j in range(7))
        np.testing.assert_allclose(total, term(Ub, pts), atol=1e-10)


def test_null_values_change_nothing(rig, base, rng):
    fans = rig.fans
    U = rng.uniform(0, 0.9, (40, 7))
    Z = rng.uniform(-0.34, 0.34, (40, 2))
    for term in (E.FanGain(fans, base), E.FanShift(fans, base), E.FanPush(fans, base), E.FanWidth(fans, base),
                 E.FanElongation(fans, base), E.FanCurve(fans, base), E.FanShape(fans, base),
                 E.Swirl(fans, base), E.JetInteraction(fans, base), E.DeadBand(fans, base),
                 base + E.Background(fans)):
        np.testing.assert_allclose(term(U, Z), base(U, Z), atol=1e-12, err_msg=repr(term))


def test_each_hypothesis_does_what_it_says(rig, base):
    fans = rig.fans
    hm2 = fans.index('HM2')
    U = np.full(7, 0.5)
    over = fans.positions[hm2][None]
    alone = np.zeros(7)
    alone[hm2] = 0.5
    own = E.fan_part(base, alone, over, hm2)[0][0]
    assert E.FanGain(fans, base, fan='HM2', gain=0.8)(alone, over)[0] == pytest.approx(
        base(alone, over)[0] - 0.2 * own)
    # a shifted jet peaks where it lands
    lm2 = fans.index('LM2')
    only = np.zeros(7)
    only[lm2] = 0.6
    shifted = E.FanShift(fans, base, fan='LM2', shift=(0.04, 0.0))
    hub = fans.positions[lm2]
    assert E.fan_part(shifted, only, [hub + (0.04, 0.0)], lm2)[0][0] == pytest.approx(
        E.fan_part(base, only, [hub], lm2)[0][0])
    # a pushed jet lands farther out along the line from the axis through its hub; CM stays
    pushed = E.FanPush(fans, base, group=E.ALL_FANS, push=0.05)
    out = hub * (1 + 0.05 / np.hypot(*hub))
    assert E.fan_part(pushed, only, [out], lm2)[0][0] == pytest.approx(
        E.fan_part(base, only, [hub], lm2)[0][0])
    np.testing.assert_allclose(E.fan_landing(pushed, lm2), E.fan_landing(base, lm2) + out - hub)
    cm = fans.index('CM')
    np.testing.assert_allclose(E.fan_part(pushed, U, rig.key_points, cm)[0],
                               E.fan_part(base, U, rig.key_points, cm)[0])
    # swirl turns a lone CCW fan's footprint by `gain` rad counter-clockwise
    quiet = FanJets(fans, thrust_higher=(0.0, 2.5, 11.0), thrust_lower=(0.0, 2.0, 8.0))  # 0 N at U = 0
    turned = E.Swirl(fans, quiet, gain=0.3)
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, -s], [s, c]]) @ fans.positions[hm2]
    assert turned(alone, [rot])[0] == pytest.approx(quiet(alone, over)[0], rel=1e-9)
    # dead band: nothing below the threshold, nothing more above saturation
    db = E.DeadBand(fans, base, threshold=0.12, saturation=0.75)
    assert db(np.full(7, 0.1), rig.key_points).max() == pytest.approx(base(np.zeros(7), rig.key_points).max())
    np.testing.assert_allclose(db(np.full(7, 0.8), rig.key_points), db(np.full(7, 0.95), rig.key_points))
    # the wall layer slows the flow more near the wall; background adds everywhere
    wall = E.WallLayer(fans, base, thickness=0.06)
    ratio = wall(U, [[0.0, 0.05], [0.0, 0.33]]) / base(U, [[0.0, 0.05], [0.0, 0.33]])
    assert 0.9 < ratio[0] <= 1.0 and ratio[1] < 0.8
    # jets interact only where neighbours meet, growing with both thrusts
    inter = E.JetInteraction(fans, base, strength=0.3)
    mid = 0.5 * (fans.positions[0] + fans.positions[1])
    extra = (inter(U, [mid]) - base(U, [mid]))[0]
    assert extra > 0.2 and len(inter.pairs) == 12
    lonely = E.JetInteraction(fans, quiet, strength=0.3)  # one fan on: no neighbour to meet
    assert (lonely(alone, [mid]) - quiet(alone, [mid]))[0] == pytest.approx(0.0, abs=0.01)
    # the mean-thrust form follows the tunnel's mean thrust, not each pair's: swapping two
    # commands within a mount group keeps it and changes the pairs' form
    mean_form = E.JetInteraction(fans, base, strength=0.3, follows='mean')
    hm1, hm3 = fans.index('HM1'), fans.index('HM3')
    a = np.array([0.2, 0.5, 0.7, 0.3, 0.6, 0.4, 0.5])
    b = a.copy()
    b[[hm1, hm3]] = a[[hm3, hm1]]
    assert fans.groups[hm1] == fans.groups[hm3]
    pts = rig.key_points
    np.testing.assert_allclose(mean_form(a, pts) - base(a, pts), mean_form(b, pts) - base(b, pts))
    assert not np.allclose(inter(a, pts) - base(a, pts), inter(b, pts) - base(b, pts))
    with pytest.raises(ConfigError, match='follows'):
        E.JetInteraction(fans, base, follows='total')


def test_elongation_keeps_the_jets_force_and_stretches_along_its_angle(rig, base):
    fans = rig.fans
    lm2 = fans.index('LM2')
    only = np.zeros(7)
    only[lm2] = 0.6
    hub = fans.positions[lm2]
    g = np.linspace(-0.6, 0.6, 121)
    grid = hub + np.array([[x, y] for x in g for y in g])
    stretched = E.FanElongation(fans, base, fan='LM2', ratio=2.0, angle=0.0)

    def part(term, pts):
        return E.fan_part(term, only, pts, lm2)[0]
    assert part(stretched, grid).sum() == pytest.approx(part(base, grid).sum(), rel=1e-3)
    along = part(stretched, [hub + (0.12, 0.0)])[0]
    across = part(stretched, [hub + (0.0, 0.12)])[0]
    assert along > part(base, [hub + (0.12, 0.0)])[0] > across


def test_bounds_selection_and_errors_name_the_problem(rig, base):
    fans = rig.fans
    with pytest.raises(ConfigError, match='gain'):
        E.FanGain(fans, base, fan='HM2', gain=5.0)
    with pytest.raises(ConfigError, match='NOPE'):
        E.FanShift(fans, base, fan='NOPE')
    with pytest.raises(ConfigError, match='fan or group'):
        E.FanGain(fans, base, fan='HM2', group='higher')
    with pytest.raises(ConfigError, match='group'):
        E.FanWidth(fans, base, group='sideways')
    with pytest.raises(ConfigError, match='shape'):
        E.WallLayer(fans, base, shape='hexagonal')
    grouped = E.FanGain(fans, base, group='higher', gain=0.9)
    assert len(grouped.theta) == len(base.theta) + 1 and E.term_label(grouped) == 'fan_gain[higher]'
    assert E.term_label(E.FanGain(fans, base, fan=['HM2', 'LM1'])) == 'fan_gain[HM2,LM1]'
    assert grouped.theta_names[-1] == 'fan_gain[higher].gain'


def test_tree_helpers_find_and_fix_parameters(rig, base):
    fans = rig.fans
    model = E.Swirl(fans, E.FanGain(fans, base, fan='HM2', gain=0.8), gain=0.2) + E.Background(fans, 0.1)
    slices = {E.term_label(n): sl for n, sl in E.param_slices(model)}
    assert model.theta[slices['fan_gain[HM2]']] == pytest.approx([0.8])
    assert model.theta[slices['swirl']] == pytest.approx([0.2])
    assert model.theta[slices['background']] == pytest.approx([0.1])
    held = E.set_fixed(model, True, lambda s: s['kind'] in ('fan_gain', 'swirl'))
    assert len(held.theta) == len(model.theta) - 2
    np.testing.assert_allclose(held(np.full(7, 0.4), rig.key_points), model(np.full(7, 0.4), rig.key_points))
    freed = E.set_fixed(held, False)
    assert len(freed.theta) == len(model.theta)
    assert E.find_term(model, 'swirl').gain == 0.2 and E.find_term(model, 'nothing') is None


def test_a_model_file_naming_library_kinds_loads_without_importing_them(rig, tmp_path):
    import subprocess
    import sys
    from wind_shaper.model.modelfile import save_model
    path = save_model(tmp_path / 'm.yaml', E.FanGain(rig.fans, FanJets(rig.fans), fan='HM2', gain=0.8))
    code = ('import sys; from wind_shaper.core.geometry import FanArray; '
            'from wind_shaper.model.modelfile import load_model; '
            f'm = load_model({str(path)!r}, FanArray.paper_rig()); '
            'assert "wind_shaper.model.fan_effects" in sys.modules; print(type(m).__name__)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == 'FanGain', out.stderr


def _plate_average(points, jet_cov, side, order=8):
    """Mean over a square plate of side ``side`` [m] centred at each point (K, 2) of a Gaussian
    jet of covariance ``jet_cov`` (2, 2) [m^2] landing at the origin (unit total force), by
    Gauss-Legendre quadrature: the truth the elongation tests compare with, computed without the
    term's own formulas."""
    x, w = np.polynomial.legendre.leggauss(order)
    nodes = np.array([(a, b) for a in x for b in x]) * side / 2.0
    weights = np.array([p * q for p in w for q in w]) / 4.0
    inv = np.linalg.inv(jet_cov)
    q = np.asarray(points, float)[:, None, :] + nodes[None]
    norm = 2 * np.pi * np.sqrt(np.linalg.det(jet_cov))
    density = np.exp(-0.5 * np.einsum('kni,ij,knj->kn', q, inv, q)) / norm
    return density @ weights


def _stretched_cov(v_jet, ratio, angle):
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    return v_jet * rot @ np.diag([ratio, 1.0 / ratio]) @ rot.T


@pytest.mark.parametrize('rho', [0.1, 0.25, 1.0])
def test_the_plates_share_of_a_stretch_is_that_of_a_square_plate(rho):
    # the share tabulated from closed forms against a direct quadrature of the plate average:
    # the change a small stretch of the jet makes, matched by least squares to the change the
    # same stretch of the averaged footprint makes, along a side and along a diagonal
    side, eps = 0.2, 1e-3
    v_jet = rho * side ** 2
    h = 0.005
    g = np.arange(-1.0, 1.0 + 1e-9, h) * 6 * np.sqrt(v_jet + side ** 2 / 12)
    X, Y = np.meshgrid(g, g)
    pts = np.column_stack([X.ravel(), Y.ravel()])
    F = _plate_average(pts, _stretched_cov(v_jet, 1.0, 0.0), side).reshape(X.shape)
    Fy, Fx = np.gradient(F, g, g)
    shares = []
    for angle, warp in ((0.0, X * Fx - Y * Fy), (np.pi / 4, X * Fy + Y * Fx)):
        change = (_plate_average(pts, _stretched_cov(v_jet, 1 + eps, angle), side).reshape(X.shape) - F) / eps
        shares.append(float(np.sum(change * -0.5 * warp) / np.sum((0.5 * warp) ** 2)))
    along, diagonal = plate_stretch_share(rho)
    assert along == pytest.approx(shares[0], rel=0.01)
    assert diagonal == pytest.approx(shares[1], rel=0.01)
    # a square passes less of a stretch on than a Gaussian plate of its variance
    assert along < diagonal < rho / (rho + 1 / 12)


@pytest.mark.parametrize('ratio,angle', [(1.6, 0.0), (1.4, 0.6), (2.0, np.pi / 4)])
def test_elongation_reads_the_jets_own_ratio_through_a_square_plate(rig, ratio, angle):
    # a Gaussian jet (10 cm per axis) averaged over the 20 cm plate, stretched; the model's
    # footprint is the Gaussian of the round average's variance. Fitted on the footprint, the
    # term reads the jet's ratio (a Gaussian plate in its place read 1.6 as about 1.55)
    from scipy.optimize import least_squares
    fans, side, v_jet = rig.fans, 0.2, 0.01
    lm2 = fans.index('LM2')
    hub = fans.positions[lm2]
    sigma = np.sqrt(2 * (v_jet + side ** 2 / 12))
    jets = FanJets(fans, thrust_higher=(0.0, 0.0, 1.0), thrust_lower=(0.0, 0.0, 1.0), sigma=sigma)
    g = np.linspace(-0.4, 0.4, 41)
    d = np.array([[x, y] for x in g for y in g])
    seen = _plate_average(d, _stretched_cov(v_jet, ratio, angle), side)
    U = np.zeros((len(d), 7))
    U[:, lm2] = 1.0

    def residual(p):
        term = E.FanElongation(fans, jets, fan='LM2', ratio=p[0], angle=p[1], plate_side=side)
        return p[2] * E.fan_part(term, U, hub + d, lm2)[0] - seen
    fit = least_squares(residual, [1.2, angle + 0.2, seen.max()],
                        bounds=([1.0, -np.pi, 0], [4.0, np.pi, np.inf]))
    assert fit.x[0] == pytest.approx(ratio, rel=0.01), fit.x
    assert (fit.x[1] - angle + np.pi / 2) % np.pi - np.pi / 2 == pytest.approx(0.0, abs=0.01)
