"""Sweeps <-> rosbag2 bags: ``read_sweeps`` rebuilds the sweeps of a recording, ``write_sweep_bag``
writes synthetic ones the way the node graph would have recorded them. No rclpy.

Reading: the bag's force (``WrenchStamped``, vertical force = ``wrench.force.z`` [N]) and plate
pose (``PoseStamped``, tunnel frame, x/y [m]) streams are cut into sweeps by the coordinator's
``IterationStatus`` (state 'sweeping' of iteration k) or, without status, by fan-command
changes (``wind_shaper.bag.segments``); inside a sweep, force and pose are paired by their
header stamps [s] exactly as the field estimator pairs them (``wind_shaper.estimation.align``: one
pair per pose, mean force over +-half a pose period). The stored sweeps of a designed experiment
(``wind-shaper collect``) are in the bag as they are in the experiment folder: one
``SweepSamples`` per stored row on /wind_shaper/experiment/sweeps, read as they are.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence
import warnings

import numpy as np

from ..estimation import align_sweep
from ..core.errors import SweepError
from ..core.tunnel import Sweep
from ..ros import names
from . import segments as seg
from . import topics as bt
from . import types
from .errors import BagContentError, BagWriteError
from .storage import BagReader, BagWriter
from .topics import SWEEP_TOPICS

NS = 1_000_000_000


@dataclass(frozen=True)
class SweepRecord:
    """A sweep found in a bag: the core ``Sweep`` (times [s] since its first pose), its
    iteration k (-1 if the bag has no status), fan order of ``sweep.pwm``, the receive-time
    interval [start_ns, end_ns) it was cut from, the raw message counts, whether it ran to its
    end, and how it was delimited ('status', 'commands' or 'whole')."""

    sweep: Sweep
    iteration: int
    fan_names: tuple[str, ...]
    start_ns: int
    end_ns: int
    n_force: int
    n_pose: int
    complete: bool
    source: str


# -- reading ----------------------------------------------------------------------------------------

def _stamp_s(header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def read_sweep_records(bag_path: Path | str, *, force_topic: str = bt.FORCE,
                       pose_topic: str = bt.PLATE_POSE, segment_by: str = 'auto',
                       include_incomplete: bool = True, strict: bool = False) -> list[SweepRecord]:
    """Every sweep in the bag at ``bag_path``, in time order, with its bookkeeping.

    segment_by: 'status' (IterationStatus 'sweeping' intervals), 'commands' (intervals of
    constant FanCommand on /wind_shaper/fans/command, else /wind_shaper/fans/applied), 'whole'
    (the whole bag is one sweep), or 'auto' (an experiment's stored rows as recorded, and the
    status intervals if the bag has any, else commands unless it holds experiment rows). include_incomplete: keep a sweep the recording cut short. Raises a BagError if the
    bag is missing, damaged, or lacks the force / pose topics. A sweep interval whose streams
    cannot be paired (no force or pose in it, clocks out of step) is skipped with a warning, or
    raises the core's SweepError when ``strict``.
    """
    if segment_by not in ('auto', 'status', 'commands', 'whole'):
        raise ValueError(f"segment_by must be 'auto', 'status', 'commands' or 'whole'; got {segment_by!r}")
    with BagReader(bag_path) as bag:
        # a graph started in a namespace records /<ns>/wind_shaper/...: read those under the
        # root names
        ns = bt.bag_namespace(bag.topics)
        topics = {bt.canonical(t): info for t, info in bag.topics.items()}
        if pose_topic not in topics and pose_topic == bt.PLATE_POSE and bt.MOCAP_POSE in topics:
            raise BagContentError(
                f'bag {bag.path} has no {bt.PLATE_POSE} (plate centre, tunnel frame) but has '
                f'{bt.MOCAP_POSE} (raw mocap frame): record the mocap_relay output too, or pass '
                f'pose_topic={bt.MOCAP_POSE!r} to pair force with mocap-frame positions')
        bag.require_topics([bt.in_namespace(t, ns) for t in (force_topic, pose_topic)],
                           'to rebuild sweeps (force and plate pose)')
        for topic, wanted in ((force_topic, types.WRENCH_STAMPED), (pose_topic, types.POSE_STAMPED)):
            if topics[topic].msgtype != wanted:
                raise BagContentError(f'bag {bag.path}: {topic} has type {topics[topic].msgtype}, '
                                      f'expected {wanted}')
        command_topic = next((t for t in (bt.FAN_COMMAND, bt.FAN_APPLIED)
                              if topics.get(t) and topics[t].count
                              and topics[t].msgtype == types.FAN_COMMAND), None)
        status_topic = (bt.STATUS if topics.get(bt.STATUS) and topics[bt.STATUS].count
                        and topics[bt.STATUS].msgtype == types.ITERATION_STATUS else None)
        rows_topic = (bt.EXPERIMENT_SWEEPS if topics.get(bt.EXPERIMENT_SWEEPS)
                      and topics[bt.EXPERIMENT_SWEEPS].count
                      and topics[bt.EXPERIMENT_SWEEPS].msgtype == types.SWEEP_SAMPLES else None)
        rows: list[SweepRecord] = []

        force_recv, force_t, force_z = [], [], []
        pose_recv, pose_t, pose_xy = [], [], []
        statuses: list[seg.StatusEvent] = []
        commands: list[seg.CommandEvent] = []
        wanted = [force_topic, pose_topic] + [t for t in (status_topic, command_topic, rows_topic) if t]
        first_ns = last_ns = None
        for topic, t_ns, msg in bag.decoded([bt.in_namespace(t, ns) for t in wanted]):
            topic = bt.canonical(topic)
            first_ns = t_ns if first_ns is None else first_ns
            last_ns = t_ns
            if topic == force_topic:
                force_recv.append(t_ns)
                force_t.append(_stamp_s(msg.header))
                force_z.append(msg.wrench.force.z)
            elif topic == pose_topic:
                pose_recv.append(t_ns)
                pose_t.append(_stamp_s(msg.header))
                pose_xy.append((msg.pose.position.x, msg.pose.position.y))
            elif topic == rows_topic:
                rows.append(_experiment_row(msg, t_ns))
            elif topic == status_topic:
                statuses.append(seg.StatusEvent(t_ns, int(msg.iteration), str(msg.state),
                                                tuple(msg.fan_names), tuple(float(u) for u in msg.pwm)))
            else:
                commands.append(seg.CommandEvent(t_ns, tuple(msg.names), tuple(float(u) for u in msg.pwm)))

    mode = segment_by
    if mode == 'auto':
        # an experiment's stored rows are its sweeps: its command changes are no others
        mode = 'status' if statuses else ('rows' if rows else 'commands')
    if mode == 'rows':
        parts = []
    elif mode == 'status':
        if not statuses:
            raise BagContentError(f'bag {bag_path} has no {bt.STATUS} messages to find the sweeps '
                                  f"by: use segment_by='commands' or 'whole'")
        parts = seg.segments_from_status(statuses, last_ns, commands)
    elif mode == 'commands':
        parts = seg.segments_from_commands(commands, first_ns, last_ns)
    else:
        parts = [seg.Segment(first_ns, last_ns + 1, -1, (), (), True, 'whole')]

    force_recv = np.asarray(force_recv, dtype=np.int64)
    pose_recv = np.asarray(pose_recv, dtype=np.int64)
    force_t, force_z = np.asarray(force_t), np.asarray(force_z)
    pose_t, pose_xy = np.asarray(pose_t), np.asarray(pose_xy, dtype=float).reshape(-1, 2)
    records = []
    for part in parts:
        if not (part.complete or include_incomplete):
            continue
        f = (force_recv >= part.start_ns) & (force_recv < part.end_ns)
        p = (pose_recv >= part.start_ns) & (pose_recv < part.end_ns)
        try:
            sweep = align_sweep(force_t[f], force_z[f], pose_t[p], pose_xy[p, 0], pose_xy[p, 1],
                                np.asarray(part.pwm, dtype=float))
        except SweepError as exc:
            where = (f'iteration {part.iteration}' if part.iteration >= 0 else
                     f'the segment at {part.start_ns * 1e-9:.3f} s')
            if strict:
                raise SweepError(f'bag {bag_path}, {where}: {exc}') from None
            warnings.warn(f'bag {bag_path}: skipped {where} ({int(f.sum())} force, {int(p.sum())} '
                          f'pose messages): {exc}', stacklevel=2)
            continue
        records.append(SweepRecord(sweep, part.iteration, part.fan_names, part.start_ns, part.end_ns,
                                   int(f.sum()), int(p.sum()), part.complete, part.source))
    if segment_by == 'auto':
        records = sorted(records + rows, key=lambda r: r.start_ns)
    return records


def _experiment_row(msg, t_ns: int) -> SweepRecord:
    """A stored row of an experiment (SweepSamples, iteration = the row) as a record."""
    n = len(msg.t)
    sweep = Sweep(np.column_stack([np.asarray(msg.x, float), np.asarray(msg.y, float)]).reshape(-1, 2),
                  np.asarray(msg.force, float), np.asarray(msg.t, float), np.asarray(msg.pwm, float))
    return SweepRecord(sweep, int(msg.iteration), tuple(msg.fan_names), int(t_ns), int(t_ns), n, n,
                       True, 'experiment')


def read_sweeps(bag_path: Path | str, **options) -> list[Sweep]:
    """The sweeps of a recorded (or ``write_sweep_bag``) bag as core ``Sweep`` objects: positions
    (M, 2) [m, tunnel frame], forces (M,) [N] paired as the field estimator pairs them, times
    [s] since the sweep's first pair, pwm = commands in force [fraction]. Options: see
    ``read_sweep_records``."""
    return [r.sweep for r in read_sweep_records(bag_path, **options)]


# -- writing ----------------------------------------------------------------------------------------

def write_sweep_bag(path: Path | str, sweeps: Sequence[Sweep], *, fan_names: Sequence[str] | None = None,
                    iterations: Sequence[int] | None = None, force_rate_hz: float = 1000.0,
                    start_time_s: float = 1_700_000_000.0, settle_s: float = 0.5, gap_s: float = 1.0,
                    pose_latency_s: float = 0.002, with_status: bool = True, with_commands: bool = True,
                    idle_streams: bool = True, estimates: Sequence | None = None,
                    key_points: np.ndarray | None = None, tunnel_from_mocap=None,
                    storage: str = 'mcap') -> Path:
    """Write ``sweeps`` as the node graph would have recorded them and return the bag path.

    For sweep k (iteration ``iterations[k]``, default k): status 'commanding', FanCommand on
    /fans/command and /fans/applied (commands = ``sweep.pwm`` [fraction], fan order
    ``fan_names``, default fan_00...), ``settle_s`` [s] later status 'sweeping' (then at 2 Hz with
    progress), the plate poses at the sweep's own sample times (``sweep.times`` [s]; a sweep
    from ``SimulatedTunnel(sample_rate_hz=100)`` gives 100 Hz) on /wind_shaper/plate/pose
    (tunnel frame) and /vrpn_mocap/plate/pose (mocap frame: ``tunnel_from_mocap``, a core
    ``RigidTransform``, identity by default), the force at ``force_rate_hz`` on
    /wind_shaper/force (``force.z`` [N]: each force sample carries the force of the nearest
    pose, so the mean over +-half a pose period around a pose is that pose's force), then
    'estimating', an optional ``FieldEstimate`` (``estimates[k]``, core FieldEstimate, with
    ``key_points``), 'updating' and 'done'; ``gap_s`` [s] later the next sweep starts.
    Between sweeps (``idle_streams``) force and pose keep streaming with the plate at rest at
    its last position. Header stamps: pose = capture time, received ``pose_latency_s`` later;
    force and the rest are stamped at reception (the bag's receive time). Bag times start at
    ``start_time_s`` [s since the epoch]. ``storage``: 'mcap' or 'sqlite3'.
    """
    sweeps = list(sweeps)
    if not sweeps:
        raise BagWriteError('write_sweep_bag needs at least one sweep')
    if not force_rate_hz > 0:
        raise BagWriteError(f'force_rate_hz must be > 0 Hz; got {force_rate_hz}')
    n_fans = len(sweeps[0].pwm)
    fan_names = tuple(fan_names) if fan_names is not None else tuple(f'fan_{i:02d}' for i in range(n_fans))
    if any(len(s.pwm) != len(fan_names) for s in sweeps):
        raise BagWriteError(f'every sweep needs {len(fan_names)} PWMs (one per fan of {fan_names})')
    iterations = list(range(len(sweeps))) if iterations is None else [int(k) for k in iterations]
    if len(iterations) != len(sweeps):
        raise BagWriteError(f'{len(iterations)} iterations given for {len(sweeps)} sweeps')
    if estimates is not None and (len(estimates) != len(sweeps)):
        raise BagWriteError(f'{len(estimates)} estimates given for {len(sweeps)} sweeps')
    if tunnel_from_mocap is None:
        from ..estimation import RigidTransform
        tunnel_from_mocap = RigidTransform.identity()
    mocap_from_tunnel = tunnel_from_mocap.inverse()

    path = Path(path)
    latency_ns = int(round(pose_latency_s * NS))
    step_ns = int(round(NS / force_rate_hz))
    events: list[tuple[int, int, str, object]] = []  # (receive ns, order, topic, payload)
    spans: list[_Span] = []  # the force stream, span by span, in time order
    clock = int(round(start_time_s * NS))
    t0 = clock
    rest_xy = np.zeros(2)

    def status(t_ns, k, state, progress=0.0, samples=0, pwm=()):
        events.append((t_ns, 0, bt.STATUS, dict(iteration=k, state=state, progress=progress,
                                                   samples=samples, pwm=tuple(pwm))))

    def rest(start_ns, end_ns):
        """The plate at rest: force (the last force) and pose (100 Hz) keep streaming."""
        if idle_streams and end_ns > start_ns:
            spans.append(_Span(start_ns, end_ns, None, None))
            for t_ns in range(start_ns + NS // 200, end_ns - NS // 100, NS // 100):
                events.append((t_ns + latency_ns, 2, 'pose', (t_ns, rest_xy.copy())))

    if with_status:
        status(clock, -1, 'idle')
    for index, (sweep, k) in enumerate(zip(sweeps, iterations)):
        pwm = tuple(float(u) for u in sweep.pwm)
        start = clock + step_ns
        if with_status:
            status(start, k, 'commanding', pwm=pwm)
        if with_commands:
            events.append((start, 1, bt.FAN_COMMAND, pwm))
            events.append((start + 50_000_000, 1, bt.FAN_APPLIED, pwm))
        sweep_start = start + int(round(settle_s * NS))
        rest(clock, sweep_start)
        times = np.asarray(sweep.times, float)
        rel = np.round((times - (times[0] if len(times) else 0.0)) * NS).astype(np.int64)
        period = int(np.median(np.diff(rel))) if len(rel) > 1 else NS // 100
        pose_ns = sweep_start + period + rel
        end = (int(pose_ns[-1]) if len(rel) else sweep_start) + period + latency_ns
        spans.append(_Span(sweep_start, end, pose_ns, np.asarray(sweep.forces, float)))
        for t_ns, xy in zip(pose_ns, np.asarray(sweep.positions, float)):
            events.append((int(t_ns) + latency_ns, 2, 'pose', (int(t_ns), xy)))
        field = (end + 50_000_000, 3, bt.FIELD, (k, estimates[index], pwm, len(rel))) \
            if estimates is not None else None
        if with_status:
            status(sweep_start, k, 'sweeping', 0.0, 0, pwm)
            for t_ns in range(sweep_start + NS // 2, end, NS // 2):
                status(t_ns, k, 'sweeping', 0.5 * (t_ns - sweep_start) / (end - sweep_start),
                       int(np.sum(pose_ns + latency_ns <= t_ns)), pwm)
            status(end, k, 'estimating', 0.5, len(rel), pwm)
            status(end + 100_000_000, k, 'updating', 0.8, len(rel), pwm)
            status(end + 200_000_000, k, 'done', 1.0, len(rel), pwm)
        if field is not None:
            events.append(field)
        if len(rel):
            rest_xy = np.asarray(sweep.positions, float)[-1]
        clock = end + 200_000_000 + (int(round(gap_s * NS)) if index + 1 < len(sweeps) else step_ns)
        rest(end, clock)
    force_events = _force_samples(spans, t0, step_ns)

    with BagWriter(path, storage=storage, custom_data={'wind_shaper': 'write_sweep_bag'}) as bag:
        for topic in SWEEP_TOPICS:
            if topic == bt.STATUS and not with_status:
                continue
            if topic in (bt.FAN_COMMAND, bt.FAN_APPLIED) and not with_commands:
                continue
            if topic == bt.FIELD and estimates is None:
                continue
            bag.add_topic(topic)
        ev = sorted(events, key=lambda e: (e[0], e[1]))
        _write_merged(bag, ev, force_events, fan_names, mocap_from_tunnel, key_points)
    return path


@dataclass(frozen=True)
class _Span:
    """A stretch of the force stream [start_ns, end_ns): a sweep (pose stamps [ns] and their
    forces [N]) or the plate at rest (both None)."""

    start_ns: int
    end_ns: int
    pose_ns: np.ndarray | None
    forces: np.ndarray | None


def _force_samples(spans, t0: int, step_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Force receive times [ns] on the global clock t0 + (j + 1/2) step, and values [N]: in a
    sweep the force of the nearest pose, at rest the last force of the previous sweep (0 before
    the first)."""
    times, values = [], []
    last_force = 0.0
    for span in spans:
        j0 = -(-(span.start_ns - t0 - step_ns // 2) // step_ns)
        j1 = -(-(span.end_ns - t0 - step_ns // 2) // step_ns)
        t = t0 + step_ns // 2 + np.arange(j0, j1, dtype=np.int64) * step_ns
        if span.pose_ns is None or len(span.pose_ns) == 0:
            f = np.full(len(t), last_force)
        else:
            pose_ns, data = span.pose_ns, span.forces
            right = np.clip(np.searchsorted(pose_ns, t), 0, len(pose_ns) - 1)
            left = np.clip(right - 1, 0, len(pose_ns) - 1)
            pick = np.where(np.abs(t - pose_ns[left]) <= np.abs(pose_ns[right] - t), left, right)
            f = data[pick]
            last_force = float(data[-1])
        times.append(t)
        values.append(f)
    return np.concatenate(times), np.concatenate(values)


def _write_merged(bag: BagWriter, events, force_events, fan_names, mocap_from_tunnel, key_points):
    T = types.typestore().types
    Time, Header = T['builtin_interfaces/msg/Time'], T['std_msgs/msg/Header']
    Vector3, Point = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Point']

    def header(t_ns, frame=''):
        return Header(stamp=Time(sec=int(t_ns // NS), nanosec=int(t_ns % NS)), frame_id=frame)

    zero = Vector3(x=0.0, y=0.0, z=0.0)
    Wrench, WrenchStamped = T['geometry_msgs/msg/Wrench'], T[types.WRENCH_STAMPED]
    Pose, PoseStamped = T['geometry_msgs/msg/Pose'], T[types.POSE_STAMPED]
    Quaternion = T['geometry_msgs/msg/Quaternion']
    q_mocap = mocap_from_tunnel.rotation
    f_times, f_values = force_events
    fi = 0

    def flush_force(until_ns):
        nonlocal fi
        while fi < len(f_times) and f_times[fi] <= until_ns:
            t_ns = int(f_times[fi])
            msg = WrenchStamped(header=header(t_ns, names.SENSOR_FRAME),
                                wrench=Wrench(force=Vector3(x=0.0, y=0.0, z=float(f_values[fi])),
                                              torque=zero))
            bag.write(bt.FORCE, t_ns, msg)
            fi += 1

    for t_ns, _, topic, payload in events:
        flush_force(t_ns)
        if topic == 'pose':
            stamp_ns, xy = payload
            p = np.array([xy[0], xy[1], 0.0])
            bag.write(bt.PLATE_POSE, t_ns, PoseStamped(
                header=header(stamp_ns, names.TUNNEL_FRAME),
                pose=Pose(position=Point(x=float(p[0]), y=float(p[1]), z=0.0),
                          orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))))
            m = mocap_from_tunnel.apply(p)
            bag.write(bt.MOCAP_POSE, t_ns, PoseStamped(
                header=header(stamp_ns, 'mocap'),
                pose=Pose(position=Point(x=float(m[0]), y=float(m[1]), z=float(m[2])),
                          orientation=Quaternion(x=float(q_mocap[0]), y=float(q_mocap[1]),
                                                 z=float(q_mocap[2]), w=float(q_mocap[3])))))
        elif topic == bt.STATUS:
            bag.write(topic, t_ns, T[types.ITERATION_STATUS](
                header=header(t_ns), iteration=payload['iteration'], state=payload['state'],
                progress=float(payload['progress']), samples=int(payload['samples']),
                coverage=float('nan'), max_std=float('nan'), message='',
                target='', fan_names=list(fan_names) if payload['pwm'] else [],
                pwm=np.asarray(payload['pwm'], dtype=np.float64), rmse=float('nan'), run_folder=''))
        elif topic in (bt.FAN_COMMAND, bt.FAN_APPLIED):
            bag.write(topic, t_ns, T[types.FAN_COMMAND](
                header=header(t_ns), names=list(fan_names), pwm=np.asarray(payload, dtype=np.float64)))
        elif topic == bt.FIELD:
            k, est, pwm, n_samples = payload
            kp = np.asarray(est.key_points if key_points is None else key_points, float)
            bag.write(topic, t_ns, T[types.FIELD_ESTIMATE](
                header=header(t_ns, names.TUNNEL_FRAME), iteration=int(k), x=kp[:, 0].copy(),
                y=kp[:, 1].copy(), mean=np.asarray(est.mean, np.float64), std=np.asarray(est.std, np.float64),
                fan_names=list(fan_names), pwm=np.asarray(pwm, np.float64), n_samples=int(n_samples),
                n_used=int(est.n_used)))
    flush_force(np.iinfo(np.int64).max)
