"""Old import paths of modules that left ``wind_shaper.core`` keep working, with a warning.

Until version 0.2 the core was one flat folder (``wind_shaper.core.model``,
``wind_shaper.core.effects``, ...). A plugin or script written against those paths still imports:
the old name resolves to the new package, and a ``DeprecationWarning`` names the import to write
instead (``from wind_shaper.model import FanGain``). Nothing inside wind_shaper uses the old
paths (test/unit/test_architecture.py checks it).
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: old module -> the package that now exports its public names
MOVED = {
    'wind_shaper.core.model': 'wind_shaper.model',
    'wind_shaper.core.effects': 'wind_shaper.model',
    'wind_shaper.core.modelfile': 'wind_shaper.model',
    'wind_shaper.core.plugins': 'wind_shaper.model.plugins',
    'wind_shaper.core.calibration': 'wind_shaper.model',
    'wind_shaper.core.field': 'wind_shaper.estimation',
    'wind_shaper.core.align': 'wind_shaper.estimation',
    'wind_shaper.core.frames': 'wind_shaper.estimation',
    'wind_shaper.core.loop': 'wind_shaper.control',
    'wind_shaper.core.update': 'wind_shaper.control',
    'wind_shaper.core.solvers': 'wind_shaper.control',
    'wind_shaper.core.secant': 'wind_shaper.control',
    'wind_shaper.core.reach': 'wind_shaper.control',
    'wind_shaper.core.targets': 'wind_shaper.control',
    'wind_shaper.core.journal': 'wind_shaper.storage',
    'wind_shaper.core.runstore': 'wind_shaper.storage',
    'wind_shaper.core.protocols': 'wind_shaper.protocols',
    'wind_shaper.core.protocols.errors': 'wind_shaper.protocols.errors',
    'wind_shaper.core.protocols.mavlink_fans': 'wind_shaper.protocols.mavlink_fans',
    'wind_shaper.core.protocols.netft': 'wind_shaper.protocols.netft',
}


class _MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old ``wind_shaper.core.X`` name to the module that replaced it."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = MOVED[spec.name]
        warnings.warn(f'{spec.name} moved: import from {new} instead (for example '
                      f'`from {new} import ...`); the old path will go in a later version',
                      DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module):
        pass  # the new module is already imported


def install() -> None:
    """Put the finder on ``sys.meta_path`` once per process."""
    if not any(isinstance(f, _MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedModuleFinder())  # before the path finder: an old
        # name must not load a second copy of the new file
