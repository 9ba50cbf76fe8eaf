"""A user-written effect for the model workbench: a gap in the flow straightener.

Load it with ``--plugin docs/examples/straightener_gap.py``. It defines

* ``StraightenerGap``, a model term (the hypothesis, with bounded parameters, registered so a
  model file can name it ``kind: straightener_gap``);
* ``FAMILIES``, which offers it to ``wind-shaper model diagnose`` as a candidate.

``stray_jet_sim.py`` beside it puts the same gap into the simulated tunnel, so the whole story
runs without a rig.
"""
import numpy as np

from wind_shaper.model import Hyper, Term, register_term
from wind_shaper.workbench.library import Candidate


@register_term
class StraightenerGap(Term):
    """Hypothesis: a gap in the honeycomb at (x, y) [m] lets extra air through, the more the
    harder the fans blow:

        Phi(U, z) = share * sum_j U_j^2 * exp(-|z - (x, y)|^2 / width^2)     [N]

    share [N] bounds 0..5 (0 = no gap); x, y [m] within the tunnel; width [m] 0.05..0.3.
    Compose with ``+``."""

    kind = 'straightener_gap'
    hypers = (Hyper('share', 1, (0.0, 5.0)), Hyper('x', 1, (-0.35, 0.35)), Hyper('y', 1, (-0.35, 0.35)),
              Hyper('width', 1, (0.05, 0.3)))

    def __init__(self, fans, share=0.0, x=0.0, y=0.0, width=0.12, fixed=()):
        self.fans = fans
        self.share, self.x, self.y, self.width = float(share), float(x), float(y), float(width)
        self._init_hypers(fixed)   # bounds and fixed parameters, as every term
        self._check_bounds()

    def _value_and_grad(self, U, Z, jacobian):
        """U (M, n_fans) commands, Z (M, 2) plate centres [m] -> force (M,) [N], dPhi/dU (M, n)."""
        G = np.exp(-((Z[:, 0] - self.x) ** 2 + (Z[:, 1] - self.y) ** 2) / self.width ** 2)
        value = self.share * np.sum(U * U, axis=1) * G
        return value, (2.0 * self.share * U * G[:, None] if jacobian else None)

    def __repr__(self):
        return (f'StraightenerGap({self.share:.3g} N sum U^2 at ({self.x:+.2f}, {self.y:+.2f}) m, '
                f'{self.width:.2f} m wide)')


def gap_family(model, geometry):
    """One candidate: a gap somewhere; screened from seven places (the centre and a ring)."""
    fans = geometry.fans

    def describe(node, std):
        s = std.get('share', [float('nan')])[0]
        return (f'a gap in the straightener at ({node.x:+.2f}, {node.y:+.2f}) m lets through '
                f'{node.share:.2f} ± {s:.2f} N per unit of sum U^2, {node.width * 100:.0f} cm wide')

    starts = [{'share': 0.2, 'x': 0.0, 'y': 0.0}] + [
        {'share': 0.2, 'x': 0.15 * np.cos(a), 'y': 0.15 * np.sin(a)} for a in np.arange(6) * np.pi / 3]
    return [Candidate('straightener_gap', 'straightener_gap', 'a gap in the straightener',
                      'extra air comes through a gap in the honeycomb', lambda m, **p: m + StraightenerGap(fans, **p),
                      'outer', 'straightener_gap', {'share': 0.0}, describe, tuple(starts))]


FAMILIES = [gap_family]
