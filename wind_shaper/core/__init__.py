"""What every part of wind_shaper reaches for: fan geometry and key points (``geometry``), the
Tunnel protocol and its sweep data (``tunnel``), YAML config reading (``config``) and the error
classes (``errors``). Nothing here imports rclpy or any other wind_shaper package.

The prior model, field estimation, the shaping loop, storage and wire codecs live in their own
packages beside this one: ``wind_shaper.model``, ``.estimation``, ``.control``, ``.storage``,
``.protocols``. Their old ``wind_shaper.core.*`` paths still import, with a warning
(``core.moved``).
"""
from . import moved as _moved

_moved.install()
