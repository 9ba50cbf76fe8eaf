"""When more iterations will not help (``StoppingRule``), for the adaptive update (``adaptive``).

Errors are mean squared differences over the key points [N^2]; the field estimate's standard
deviation at each key point [N].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import ConfigError


@dataclass(frozen=True)
class StoppingRule:
    """When more iterations will not help.

    The next step's predicted improvement of the error [N^2] is compared with the noise of the
    error estimate: with per-key-point estimate noise sigma_i = sqrt(std_i^2 + floor^2) [N]
    (GP standard deviation, floored), a step whose predicted gain is below ``factor`` x
    mean(sigma^2) could not be told apart from noise by the next sweep. The rule fires after
    ``patience`` such iterations in a row, never before ``min_iterations`` updates.
    """

    factor: float = 0.5
    floor: float = 0.05
    patience: int = 1
    min_iterations: int = 2

    def __post_init__(self):
        if not (self.factor >= 0 and self.floor >= 0 and self.patience >= 1 and self.min_iterations >= 0):
            raise ConfigError(f'stopping rule needs factor, floor >= 0, patience >= 1, '
                              f'min_iterations >= 0; got {self}')

    def noise(self, std) -> float:
        """mean(std^2 + floor^2) [N^2]: the error a sweep cannot resolve."""
        s2 = 0.0 if std is None else float(np.mean(np.asarray(std, dtype=float) ** 2))
        return s2 + self.floor ** 2

    def quiet(self, predicted_improvement: float, std) -> bool:
        """True if this step's predicted improvement [N^2] is below the noise."""
        return predicted_improvement < self.factor * self.noise(std)

    def __call__(self, k: int, predicted_improvement: float, std, history=()) -> tuple[bool, str]:
        """(stop, reason) at iteration k, given the earlier iterations' ``info['quiet']``."""
        quiet = self.quiet(predicted_improvement, std)
        streak = 1 if quiet else 0
        if quiet:
            for past in reversed(tuple(history)):
                if not dict(past.info).get('quiet', False):
                    break
                streak += 1
        if k + 1 < self.min_iterations or streak < self.patience:
            return False, ''
        return True, (f'predicted improvement {predicted_improvement:.2e} N^2 is below '
                      f'{self.factor:g} x the estimate noise {self.noise(std):.2e} N^2 for '
                      f'{streak} iteration(s)')
