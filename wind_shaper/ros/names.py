"""Topic, service and node names of the wind_shaper graph (the contract between nodes).

The graph's names are *relative* (``wind_shaper/fans/command``): they resolve under the nodes'
ROS namespace, ``/`` by default (``/wind_shaper/fans/command``), ``/tunnel_b`` for a graph
started with ``wind-shaper --namespace tunnel_b up`` (``/tunnel_b/wind_shaper/fans/command``),
so two tunnels, or the robot's stack, share a ROS domain without clashes. Two names stay
absolute: ``/diagnostics`` (one aggregator per domain) and the raw motion-capture topic, which
belongs to the mocap driver (vrpn_mocap style). Nodes read these as parameter defaults, so a lab
can remap any of them. ``resolve`` gives a name's absolute form, as ROS resolves it (what bags,
messages and ``ros2`` commands show).
"""
from __future__ import annotations

import os
import re

#: The environment variable the command line reads the namespace from (``--namespace`` sets it).
NAMESPACE_ENV = 'WIND_SHAPER_NAMESPACE'

# Nodes (node name = module name in wind_shaper.nodes)
FAN_OUTPUT = 'fan_output'
FORCE_SENSOR = 'force_sensor'
MOCAP_RELAY = 'mocap_relay'
FIELD_ESTIMATOR = 'field_estimator'
COORDINATOR = 'coordinator'
SIM_TUNNEL = 'sim_tunnel'
LIVE_VIEW = 'live_view'                          # optional: up --live / --foxglove
GRAPH_NODES = (FAN_OUTPUT, FORCE_SENSOR, MOCAP_RELAY, FIELD_ESTIMATOR, COORDINATOR)

# Topics
FAN_COMMAND = 'wind_shaper/fans/command'        # wind_shaper_msgs/FanCommand: wanted PWMs
FAN_APPLIED = 'wind_shaper/fans/applied'        # wind_shaper_msgs/FanCommand: read back from the autopilot
FORCE = 'wind_shaper/force'                     # geometry_msgs/WrenchStamped, sensor frame [N, N m]
FORCE_BLOCK = 'wind_shaper/force/block'         # wind_shaper_msgs/ForceBlock: the same samples, tens at a time
MOCAP_POSE = '/vrpn_mocap/plate/pose'            # geometry_msgs/PoseStamped, mocap frame (raw)
PLATE_POSE = 'wind_shaper/plate/pose'           # geometry_msgs/PoseStamped, tunnel frame, plate centre
FIELD = 'wind_shaper/field'                     # wind_shaper_msgs/FieldEstimate
FIELD_PARTIAL = 'wind_shaper/field/partial'     # wind_shaper_msgs/FieldEstimate of the sweep so far (each peek)
STATUS = 'wind_shaper/iteration/status'         # wind_shaper_msgs/IterationStatus
EXPERIMENT_STATUS = 'wind_shaper/experiment/status'  # wind_shaper_msgs/ExperimentStatus
EXPERIMENT_SWEEPS = 'wind_shaper/experiment/sweeps'  # wind_shaper_msgs/SweepSamples: each stored row
DIAGNOSTICS = '/diagnostics'                     # diagnostic_msgs/DiagnosticArray

# Services
RUN_ITERATION = 'wind_shaper/run_iteration'     # wind_shaper_msgs/RunIteration
CANCEL_ITERATION = 'wind_shaper/cancel_iteration'  # std_srvs/Trigger (an iteration or an experiment)
COLLECT = 'wind_shaper/collect'                 # wind_shaper_msgs/Collect (a designed experiment)
HOLD_POINT = 'wind_shaper/hold_point'           # wind_shaper_msgs/HoldPoint (a held-plate calibration point)
SET_MODEL = 'wind_shaper/set_model'             # wind_shaper_msgs/SetModel
BEGIN_SWEEP = 'wind_shaper/field_estimator/begin_sweep'  # std_srvs/Trigger
ESTIMATE_FIELD = 'wind_shaper/field_estimator/estimate'  # wind_shaper_msgs/EstimateField
QUERY_FIELD = 'wind_shaper/field/query'        # wind_shaper_msgs/QueryField (force at any positions)
SWEEP = 'wind_shaper/tunnel/sweep'              # wind_shaper_msgs/Sweep (plate motion)
STOP_SWEEP = 'wind_shaper/tunnel/stop_sweep'    # std_srvs/Trigger (end the running sweep now)
PLACE = 'wind_shaper/tunnel/place'              # wind_shaper_msgs/Place (plate to a point, held)
FORCE_BIAS = 'wind_shaper/force_sensor/bias'    # std_srvs/Trigger
EMERGENCY_STOP = 'wind_shaper/fans/emergency_stop'  # std_srvs/Trigger (latches)
RESET_STOP = 'wind_shaper/fans/reset_stop'      # std_srvs/Trigger


_TOKEN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*\Z')


def check_namespace(namespace: str | None) -> str:
    """``namespace`` as an absolute ROS namespace (``tunnel_b`` -> ``/tunnel_b``; '' or None ->
    ``/``); ValueError says what is wrong with one that is not a valid ROS namespace."""
    ns = (namespace or '').strip()
    if ns in ('', '/'):
        return '/'
    absolute = ns if ns.startswith('/') else '/' + ns
    tokens = absolute[1:].split('/')
    if absolute.endswith('/'):
        bad = 'a trailing /'
    else:
        bad = next(('an empty name between two /' if not t else repr(t) for t in tokens
                    if not _TOKEN.match(t)), '')
    if bad:
        raise ValueError(
            f'{namespace!r} is not a valid ROS namespace: it must be names separated by "/", each '
            f'starting with a letter or "_" and holding only letters, digits and "_" (e.g. '
            f'tunnel_b or /lab/tunnel_b); the bad part: {bad}')
    return absolute


def namespace_from_env() -> str:
    """The namespace the command line uses: ``$WIND_SHAPER_NAMESPACE`` (checked), else ``/``."""
    return check_namespace(os.environ.get(NAMESPACE_ENV, ''))


def resolve(name: str, namespace: str | None = None) -> str:
    """The absolute name of ``name`` for a node in ``namespace`` (default: the command line's,
    ``namespace_from_env``): absolute names are kept."""
    if name.startswith('/'):
        return name
    ns = namespace_from_env() if namespace is None else check_namespace(namespace)
    return ('' if ns == '/' else ns) + '/' + name


def folder_part(namespace: str) -> str:
    """A namespace as a folder name ('' for the root namespace; ``/lab/tunnel_b`` ->
    ``lab_tunnel_b``): what keeps two namespaced graphs' run folders and journals apart."""
    ns = check_namespace(namespace)
    return '' if ns == '/' else ns.strip('/').replace('/', '_')


# Frames
TUNNEL_FRAME = 'tunnel'
SENSOR_FRAME = 'force_sensor'
