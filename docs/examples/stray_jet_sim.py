"""For the demonstration only: a gap in the flow straightener as a hidden effect of the simulated
tunnel. Load with ``--plugin docs/examples/stray_jet_sim.py`` and switch on with
``--hidden stray_jet`` (parameters x, y [m], share [-] of the total thrust, width [m])."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wind_shaper.sim.effects import HIDDEN_EFFECTS, HiddenEffect
from wind_shaper.sim.physics import FlatTop, JetGroup


@dataclass(frozen=True)
class StrayJet(HiddenEffect):
    """A jet of ``share`` x the total thrust [N] lands at (x, y) [m], ``width`` [m] wide."""

    x: float = 0.0
    y: float = -0.13
    share: float = 0.1
    width: float = 0.08
    name: ClassVar[str] = 'stray_jet'

    def sources(self, groups, thrust, geometry):
        return groups + [JetGroup(FlatTop(2.0), np.array([[self.x, self.y]]),
                                  np.array([self.share * float(np.sum(thrust))]),
                                  np.array([self.width]), np.array([-1]))]


HIDDEN_EFFECTS.setdefault(StrayJet.name, StrayJet)
