"""Message types for bags, without rclpy: a rosbags typestore of ROS 2 Jazzy plus wind_shaper_msgs.

The standard types (std_msgs, geometry_msgs, diagnostic_msgs, builtin_interfaces) come from
rosbags' bundled Jazzy store; wind_shaper_msgs is registered from its ``.msg`` files, found in
the installed share folder (ament index: ``<prefix>/share/wind_shaper_msgs/msg``) or else in the
source tree (``msg_defs/msg``). The type hashes (RIHS01) rosbags computes from that text are the
ones rosidl generates, so bags carry the same ``type_description_hash`` as a real ``ros2 bag``.
"""
from __future__ import annotations

from functools import lru_cache
import os
from pathlib import Path
import sys

from .errors import BagContentError

MSGS_PACKAGE = 'wind_shaper_msgs'

# Registered names (``package/msg/Type``) of the graph's topic types.
WRENCH_STAMPED = 'geometry_msgs/msg/WrenchStamped'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
FAN_COMMAND = 'wind_shaper_msgs/msg/FanCommand'
FIELD_ESTIMATE = 'wind_shaper_msgs/msg/FieldEstimate'
ITERATION_STATUS = 'wind_shaper_msgs/msg/IterationStatus'
EXPERIMENT_STATUS = 'wind_shaper_msgs/msg/ExperimentStatus'
SWEEP_SAMPLES = 'wind_shaper_msgs/msg/SweepSamples'

_SOURCE_MSG_DIR = Path(__file__).resolve().parents[2] / 'msg_defs' / 'msg'


def msg_dir() -> Path:
    """The folder holding wind_shaper_msgs' ``.msg`` files: installed share folder first (ament
    index, then this interpreter's prefix), then the source tree. Raises BagContentError if none
    has them."""
    candidates = []
    try:
        from ament_index_python.packages import (PackageNotFoundError,
                                                 get_package_share_directory)
        try:
            candidates.append(Path(get_package_share_directory(MSGS_PACKAGE)) / 'msg')
        except (PackageNotFoundError, ValueError, LookupError):
            pass
    except ImportError:  # no ROS: a plain Python install of wind_shaper
        pass
    for prefix in [*os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep), sys.prefix]:
        if prefix:
            candidates.append(Path(prefix) / 'share' / MSGS_PACKAGE / 'msg')
    candidates.append(_SOURCE_MSG_DIR)
    for folder in candidates:
        if folder.is_dir() and any(folder.glob('*.msg')):
            return folder
    raise BagContentError(
        f'cannot find the {MSGS_PACKAGE} .msg files (looked in '
        f'{", ".join(str(c) for c in dict.fromkeys(candidates))}): run `bash tools/dev.sh setup` '
        f'or source the workspace that built {MSGS_PACKAGE}')


@lru_cache(maxsize=None)
def _typestore_for(folder: str):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted(Path(folder).glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'{MSGS_PACKAGE}/msg/{path.stem}'))
    store.register(types)
    return store


def typestore(folder: Path | str | None = None):
    """The rosbags typestore (ROS 2 Jazzy + wind_shaper_msgs), built once per ``.msg`` folder."""
    return _typestore_for(str(Path(folder) if folder is not None else msg_dir()))


def require_type(msgtype: str, store=None) -> None:
    """Raise BagContentError unless ``msgtype`` ('pkg/msg/Type') is known to the typestore."""
    store = store if store is not None else typestore()
    if msgtype not in store.fielddefs:
        raise BagContentError(
            f'message type {msgtype!r} is unknown to the bag typestore (ROS 2 Jazzy standard '
            f'types + {MSGS_PACKAGE}): record only topics of those types')


def has_header(msgtype: str, store=None) -> bool:
    """True if the type's first field is a ``std_msgs/msg/Header`` (its stamp can be shifted)."""
    store = store if store is not None else typestore()
    fields = store.fielddefs.get(msgtype, (None, []))[1]
    if not fields:
        return False
    name, (kind, ref) = fields[0]
    from rosbags.typesys.base import Nodetype
    return name == 'header' and kind == Nodetype.NAME and ref == 'std_msgs/msg/Header'
