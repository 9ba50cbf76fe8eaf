"""sim_tunnel node: the simulated tunnel behind the rig's own protocols, on 127.0.0.1 only.

Plays the rig so that fan_output, force_sensor and mocap_relay run unchanged against it:

* a MAVLink 2 autopilot on UDP ``127.0.0.1:mavlink_port`` (``SimAutopilot``): the pulses it
  applies [us] are mapped back to PWM fractions with the same channel map as fan_output
  (``fan_names``, ``channels``, ``pwm_min_us``, ``pwm_max_us``) and applied to the plant;
* an ATI Net F/T RDT server on UDP ``127.0.0.1:netft_port`` (``SimNetFtServer``) streaming at
  ``netft_rate_hz`` (``netft_records_per_datagram`` records per datagram) the plant's vertical
  plate force [N] (Fz, sensor frame, positive up) at the plate's current position: the true
  plate-averaged field plus the simulator's noise model;
* ``geometry_msgs/PoseStamped`` of the plate's tracked rigid body on ``/vrpn_mocap/plate/pose``
  at ``mocap_rate_hz`` in the mocap frame (stamped with capture time): pose =
  inverse(tunnel_from_mocap) * plate * inverse(plate_offset), with the noise model's jitter, so
  the mocap_relay with the same parameters gets the plate centre back in the tunnel frame;
* service ``/wind_shaper/tunnel/sweep`` (``wind_shaper_msgs/Sweep``): moves the plate along the
  simulator's sweep path in real time, sped up to cover the sweep disc in ``duration_s``, and
  returns when it is back at ``rest_position`` (outside the key-point disc);
* service ``/wind_shaper/tunnel/stop_sweep`` (``std_srvs/Trigger``): ends the running sweep now
  (the coordinator's estimate is good enough) and sends the plate back to rest;
* service ``/wind_shaper/tunnel/place`` (``wind_shaper_msgs/Place``): moves the plate to a point
  and holds it there, as a motion stage does for the held-plate batch;
* ``/diagnostics`` once per ``diagnostics_period_s``.

The plant, the sweep planning and the frames are pure code in ``wind_shaper.sim.live``.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from std_srvs.srv import Trigger
from wind_shaper_msgs.srv import Place, Sweep

from ..app import Setup, hidden_effects
from ..core.area import SweepArea
from ..core.errors import ConfigError, WindShaperError
from ..protocols.errors import ProtocolConfigError
from ..protocols.mavlink_fans import FanChannel, FanChannelMap
from ..ros import diagnostics, names, qos
from ..ros.convert import seconds_to_stamp
from ..ros.params import declare_parameters, param
from ..ros.runner import run
from ..sim import SimAutopilot, SimNetFtServer
from ..sim.live import LiveTunnel, MocapFrame

HOST = '127.0.0.1'   # the simulated rig never listens beyond loopback
_PAPER_FANS = ('LM1', 'HM1', 'LM2', 'HM2', 'LM3', 'HM3', 'CM')


def _clock_offset() -> float:
    """ROS (system) clock minus the monotonic clock [s], from the tightest of a few readings."""
    best = None
    for _ in range(20):
        a = time.monotonic()
        wall = time.time()
        b = time.monotonic()
        if best is None or b - a < best[0]:
            best = (b - a, wall - 0.5 * (a + b))
    return best[1]


@dataclass(frozen=True)
class SimTunnelParams:
    config_dir: str = param('', 'folder holding tunnel.yaml and sim.yaml ("" = the shipped config)')
    seed: int = param(-1, 'simulator seed of sweeps and noise; -1 = the seed in sim.yaml', low=-1)
    hidden: str = param('', "hidden effects switched on in the simulated tunnel, ';' between them, "
                        "each EFFECT[:key=value,...] as `--hidden` takes it (e.g. "
                        "'weak_fan:fan=HM2,gain=0.8'); '' = none")
    mavlink_port: int = param(14550, 'UDP port of the simulated autopilot on 127.0.0.1 '
                              '(0 = any free port)', low=0, high=65535)
    flavour: str = param('ardupilot_servo', 'autopilot flavour: ardupilot_servo, '
                         'ardupilot_rc_override or px4_actuator (only the HEARTBEAT differs)')
    fan_names: tuple = param(_PAPER_FANS, 'fans on the autopilot outputs, as in tunnel.yaml '
                             '(same as fan_output)', array_of=str)
    channels: tuple = param(tuple(range(1, 8)), 'servo output (1..16) of each fan in fan_names '
                            '(same as fan_output)', array_of=int)
    pwm_min_us: int = param(1000, 'pulse at PWM fraction 0 [us] (same as fan_output)', low=1, high=5000)
    pwm_max_us: int = param(2000, 'pulse at PWM fraction 1 [us] (same as fan_output)', low=1, high=5000)
    netft_port: int = param(49152, 'UDP port of the simulated Net F/T on 127.0.0.1 (0 = any free '
                            'port)', low=0, high=65535)
    netft_rate_hz: float = param(1000.0, 'RDT record rate [Hz]', low=1.0, high=7000.0)
    netft_records_per_datagram: int = param(1, 'RDT records per UDP datagram, as a Net F/T with '
                                            'RDT buffering sends them (1 = one per datagram)',
                                            low=1, high=40)
    counts_per_force: float = param(1_000_000.0, 'sensor counts per N (same as force_sensor)', low=1.0)
    counts_per_torque: float = param(1_000_000.0, 'sensor counts per N m (same as force_sensor)', low=1.0)
    mocap_topic: str = param(names.MOCAP_POSE, 'raw mocap pose topic (geometry_msgs/PoseStamped)')
    mocap_frame: str = param('mocap', 'frame_id of the mocap poses')
    mocap_rate_hz: float = param(100.0, 'mocap pose rate [Hz]', low=1.0, high=1000.0)
    tunnel_from_mocap: tuple = param((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
                                     'pose of the mocap frame in the tunnel frame: tx ty tz [m] '
                                     'qx qy qz qw (same as mocap_relay)', array_of=float)
    plate_offset: tuple = param((0.0, 0.0, 0.0), 'rigid body origin -> plate centre in the body '
                                'frame [m] (same as mocap_relay)', array_of=float)
    plate_height_m: float = param(0.35, 'height of the measurement plane above the fan plane '
                                  '(tunnel z of the plate centre) [m]')
    rest_position: tuple = param((0.0, -0.34), 'where the plate waits between sweeps, x y '
                                 '[m, tunnel frame]; outside the key-point disc', array_of=float)
    transit_s: float = param(0.3, 'shortest move between the rest position and the sweep path [s] '
                             '(longer if max_sweep_speed needs; at most 25 % of a sweep)',
                             low=0.0, high=10.0)
    max_sweep_speed: float = param(2.5, 'fastest plate speed of a sweep [m/s]; a sweep too short '
                                   'to cover the disc at it uses wider lanes', low=0.01)
    max_sweep_duration_s: float = param(600.0, 'longest sweep accepted [s]', low=0.1)
    force_grid_step_m: float = param(0.01, 'pitch of the tabulated force field [m]',
                                     low=0.001, high=0.05)
    diagnostics_period_s: float = param(1.0, 'period of /diagnostics [s]', low=0.1, high=60.0)

    def __post_init__(self):
        if len(self.fan_names) != len(self.channels):
            raise ConfigError(f'fan_names has {len(self.fan_names)} entries but channels '
                              f'{len(self.channels)}: give one servo output per fan')
        if not self.pwm_min_us < self.pwm_max_us:
            raise ConfigError(f'pwm_min_us {self.pwm_min_us} must be below pwm_max_us {self.pwm_max_us}')
        if len(self.tunnel_from_mocap) != 7:
            raise ConfigError('tunnel_from_mocap needs 7 numbers: tx ty tz qx qy qz qw')
        if len(self.plate_offset) != 3:
            raise ConfigError('plate_offset needs 3 numbers: x y z [m]')
        if len(self.rest_position) != 2:
            raise ConfigError('rest_position needs 2 numbers: x y [m]')


class SimTunnel(Node):
    """The simulated rig (see the module docstring)."""

    def __init__(self, **kwargs):
        super().__init__(names.SIM_TUNNEL, **kwargs)
        self.live = self._autopilot = self._netft = self._mocap_thread = None
        self._stop = threading.Event()
        try:
            self._start()
        except BaseException:
            self._close_links()
            super().destroy_node()
            raise

    def _start(self) -> None:
        self.params = p = declare_parameters(self, SimTunnelParams)
        setup = Setup.load(p.config_dir or None)
        effects = hidden_effects([e.strip() for e in p.hidden.split(';') if e.strip()])
        sim = setup.make_sim(seed=None if p.seed < 0 else p.seed, effects=effects)
        self.fan_names = list(setup.geometry.fans.names)
        unknown = [n for n in p.fan_names if n not in self.fan_names]
        if unknown:
            raise ConfigError(f'fan_names {unknown} are not fans of {setup.config_dir}/tunnel.yaml '
                              f'({", ".join(self.fan_names)}); fix fan_names in config/sim_tunnel.yaml')
        try:
            self.channel_map = FanChannelMap(
                FanChannel(name, int(ch), p.pwm_min_us, p.pwm_max_us, p.pwm_min_us)
                for name, ch in zip(p.fan_names, p.channels))
        except ProtocolConfigError as exc:
            raise ConfigError(f'channel map: {exc}') from None
        unmapped = [n for n in self.fan_names if n not in p.fan_names]
        if unmapped:
            self.get_logger().warn(f'fans {unmapped} have no autopilot output: they stay off')
        self.live = LiveTunnel(sim, p.rest_position, grid_step=p.force_grid_step_m,
                               force_rate_hz=p.netft_rate_hz, transit_s=p.transit_s,
                               max_speed=p.max_sweep_speed)
        self.live.start_worker()
        self._mocap_tf = MocapFrame(p.tunnel_from_mocap, p.plate_offset)
        self._index = {n: i for i, n in enumerate(self.fan_names)}
        self.mocap_published = 0
        self.sweeps_done = 0
        try:
            self._autopilot = SimAutopilot(HOST, p.mavlink_port, flavour=p.flavour, n_channels=16,
                                           on_outputs=self._on_outputs, safe_us=p.pwm_min_us,
                                           pwm_min_us=p.pwm_min_us, pwm_max_us=p.pwm_max_us)
            self._netft = SimNetFtServer(self._force_source, HOST, p.netft_port, p.netft_rate_hz,
                                         p.counts_per_force, p.counts_per_torque,
                                         records_per_datagram=p.netft_records_per_datagram)
        except OSError as exc:
            raise ConfigError(f'cannot open the simulated rig on {HOST} (MAVLink port '
                              f'{p.mavlink_port}, Net F/T port {p.netft_port}): {exc}; another '
                              f'sim_tunnel may be running: stop it or change the ports') from None
        except ProtocolConfigError as exc:
            raise ConfigError(str(exc)) from None

        self._pose_pub = self.create_publisher(PoseStamped, p.mocap_topic, qos.STREAM)
        self._diag_pub = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        # Reentrant: the sweep coroutine awaits a timer, which a mutually exclusive group would
        # hold back until the coroutine ended. LiveTunnel refuses a second sweep while one runs.
        self._sweep_group = ReentrantCallbackGroup()
        self.create_service(Sweep, names.SWEEP, self._handle_sweep, callback_group=self._sweep_group)
        self.create_service(Place, names.PLACE, self._handle_place, callback_group=self._sweep_group)
        self._motion_ended = None
        self.create_service(Trigger, names.STOP_SWEEP, self._handle_stop_sweep,
                            callback_group=self._sweep_group)
        self.create_timer(p.diagnostics_period_s, self._publish_diagnostics)
        self._mocap_thread = threading.Thread(target=self._mocap_loop, name='sim-mocap', daemon=True)
        self._mocap_thread.start()
        self.get_logger().info(
            f'simulated tunnel ({len(self.fan_names)} fans, seed {sim.seed}): MAVLink autopilot '
            f'udp {HOST}:{self.mavlink_port} ({p.flavour}), Net F/T udp {HOST}:{self.netft_port} '
            f'at {p.netft_rate_hz:g} Hz, mocap {p.mocap_topic} at {p.mocap_rate_hz:g} Hz, sweep '
            f'service {self.resolve_service_name(names.SWEEP)}')

    # ------------------------------------------------------------------ properties
    @property
    def mavlink_port(self) -> int:
        return self._autopilot.port

    @property
    def netft_port(self) -> int:
        return self._netft.port

    # ------------------------------------------------------------------ rig peers
    def _on_outputs(self, pulses: dict[int, int]) -> None:
        """Autopilot thread: applied pulses {channel: us} -> fractions -> the plant."""
        fractions = self.channel_map.fractions_from_pulses(pulses)
        pwm = np.zeros(len(self.fan_names))
        for name, u in fractions.items():
            pwm[self._index[name]] = u
        self.live.apply(pwm)

    def _force_source(self, t: float):
        """Net F/T thread: (Fx, Fy, Fz [N], Tx, Ty, Tz [N m]) on the plate at the record's sample
        time (t [s] since the stream started). A busy host makes the server send records in
        catch-up batches; each must still carry the force where the plate was at its own time,
        as a real sensor's would."""
        return 0.0, 0.0, self.live.force(self._netft.stream_start + t), 0.0, 0.0, 0.0

    def _mocap_loop(self) -> None:
        """Camera frames at exact ticks k / mocap_rate_hz: each pose is the plate at its tick,
        stamped with the tick (capture time), published as soon as the thread gets to it (a late
        thread adds latency, not jitter; more than 10 frames behind, it drops frames)."""
        period = 1.0 / self.params.mocap_rate_hz
        tick = time.monotonic()
        clock_offset, next_sync = _clock_offset(), tick + 5.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now < tick:
                self._stop.wait(tick - now)
                continue
            if now - tick > 10 * period:
                tick += period * int((now - tick) / period)
            if now > next_sync:   # follow a step of the system clock (not reading jitter)
                fresh, next_sync = _clock_offset(), now + 5.0
                if abs(fresh - clock_offset) > 0.1:
                    self.get_logger().warn(f'system clock stepped by {fresh - clock_offset:+.3f} s')
                    clock_offset = fresh
            try:
                self._publish_mocap(tick, tick + clock_offset)
            except Exception as exc:   # e.g. the context shut down under us
                if not self._stop.is_set():
                    self.get_logger().error(f'mocap publish failed: {exc}')
                return
            tick += period

    def _publish_mocap(self, t: float, stamp_s: float) -> None:
        """One pose of the plate at monotonic time t [s], stamped stamp_s [s, ROS clock]: the
        stamp and the position belong to the same instant."""
        reading = self.live.mocap_position(t)
        if reading is None:   # a dropout: the mocap sends nothing
            return
        p = self.params
        pos, quat = self._mocap_tf.body_pose((reading[0], reading[1], p.plate_height_m))
        msg = PoseStamped()
        msg.header.stamp = seconds_to_stamp(stamp_s)
        msg.header.frame_id = p.mocap_frame
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = pos
        (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
         msg.pose.orientation.w) = quat
        self._pose_pub.publish(msg)
        self.mocap_published += 1

    # ------------------------------------------------------------------ services
    async def _motion_end(self, motion) -> None:
        """Return when ``motion`` ends (or a stop_sweep request ends it): awaited in a
        coroutine, so the executor's one thread serves diagnostics while the plate moves."""
        ended = Future()
        self._motion_ended = ended
        timer = self.create_timer(max(motion.end - time.monotonic(), 1e-3),
                                  lambda: ended.done() or ended.set_result(True),
                                  callback_group=self._sweep_group)
        try:
            await ended
        finally:
            self._motion_ended = None
            self.destroy_timer(timer)

    def _handle_stop_sweep(self, request: Trigger.Request, response: Trigger.Response):
        ended = self._motion_ended
        if ended is None or not self.live.sweeping():
            response.success, response.message = False, 'no sweep is running'
            return response
        self.live.stop_sweep()            # the plate goes straight back to rest
        if not ended.done():
            ended.set_result(True)
        response.success, response.message = True, 'sweep ended early; the plate returns to rest'
        return response

    async def _handle_place(self, request: Place.Request, response: Place.Response) -> Place.Response:
        try:
            motion = self.live.place(float(request.x), float(request.y))
        except WindShaperError as exc:
            response.success, response.message = False, str(exc)
            return response
        await self._motion_end(motion)
        response.success = True
        response.message = f'the plate is at ({request.x:+.3f}, {request.y:+.3f}) m'
        return response

    async def _handle_sweep(self, request: Sweep.Request, response: Sweep.Response) -> Sweep.Response:
        limit = self.params.max_sweep_duration_s
        if not 0 < request.duration_s <= limit:
            response.success = False
            response.message = (f'duration_s must be in (0, {limit:g}] s; got {request.duration_s:g} '
                                f'(the limit is the max_sweep_duration_s parameter)')
            return response
        t_start = time.monotonic()
        try:
            region = sweep_area(request, self.live.geometry.sweep_radius)
            motion = self.live.start_sweep(request.duration_s, int(request.seed), region=region)
        except WindShaperError as exc:
            response.success = False
            response.message = str(exc)
            return response
        where = '' if region is None else f' over {region.text()}'
        self.get_logger().info(f'sweep of {request.duration_s:g} s started{where}')
        await self._motion_end(motion)
        response.duration_s = time.monotonic() - t_start
        if self._stop.is_set():
            self.live.stop_sweep()
            response.success = False
            response.message = 'the sim_tunnel node is shutting down; the sweep was cut short'
            return response
        self.sweeps_done += 1
        response.success = True
        early = ' (ended early on request)' if response.duration_s < request.duration_s - 0.05 else ''
        response.message = f'swept for {response.duration_s:.2f} s{early}; the plate is back at rest'
        return response

    # ------------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        live = self.live
        x, y = live.position()
        ap, ft = self._autopilot, self._netft
        current = live.field_current
        values = {
            'pwm': ' '.join(f'{n}={u:.3f}' for n, u in zip(self.fan_names, live.pwm)),
            'force_field_current': current,
            'plate_position_m': f'{x:.3f} {y:.3f}',
            'sweeping': live.sweeping(),
            'sweeps_done': self.sweeps_done,
            'mavlink_peer': ap.peer,
            'netft_client': ft.client,
            'netft_streaming': ft.streaming,
            'netft_records': ft.fault_log().generated,
            'mocap_published': self.mocap_published,
        }
        message = 'running' if current else 'force field being recomputed for new fan commands'
        self._diag_pub.publish(diagnostics.array(self, diagnostics.status(
            f'{names.SIM_TUNNEL}: simulated rig', diagnostics.OK, message, values, 'sim')))

    # ------------------------------------------------------------------ shutdown
    def _close_links(self) -> None:
        self._stop.set()
        # one deadline for all the threads, within `up`'s 5 s grace: each waited up to 2 s in
        # turn, 8 s in all (`up` SIGKILLed a sim_tunnel after a SIGINT once, in a test run)
        deadline = time.monotonic() + 3.0

        def left() -> float:
            return max(0.1, deadline - time.monotonic())
        if self._mocap_thread is not None:
            self._mocap_thread.join(left())
        for link in (self._autopilot, self._netft, self.live):
            if link is not None:
                link.close(left())

    def destroy_node(self):
        self._close_links()
        return super().destroy_node()


#: Most region points a Sweep request may give: a region is made of key points (317 on the paper's
#: rig), and planning a path around K points costs K x K distances.
MAX_REGION_POINTS = 2000
#: Smallest region reach a Sweep request may give [m]: lanes are planned at a fraction of it, and
#: a reach of a few micrometres planned a path without end (the shipped reach is 0.10 m).
MIN_REGION_REACH_M = 0.01


def sweep_area(request: Sweep.Request, radius: float) -> SweepArea | None:
    """A Sweep request's region (None: the whole disc of ``radius`` [m]); ConfigError says what is
    wrong with it: more than MAX_REGION_POINTS points, x and y of different lengths, a reach
    outside [MIN_REGION_REACH_M, the disc's diameter], a point not finite or out of reach of
    the disc."""
    n_x, n_y = len(request.region_x), len(request.region_y)
    if n_x == 0 and n_y == 0:
        return None
    if max(n_x, n_y) > MAX_REGION_POINTS:
        raise ConfigError(f'the sweep region has {max(n_x, n_y)} points, more than the '
                          f'{MAX_REGION_POINTS} a sweep plans around: send the key points the '
                          f'region needs')
    if n_x != n_y:
        raise ConfigError(f'the sweep region has {n_x} x but {n_y} '
                          f'y values: give one (x, y) per region point')
    reach = float(request.region_reach)
    if not MIN_REGION_REACH_M <= reach <= 2 * radius:
        raise ConfigError(f'the sweep region needs reach > 0 m, within [{MIN_REGION_REACH_M:g}, '
                          f'{2 * radius:g}] m (the sweep disc\'s diameter); got {reach!r}')
    centres = np.column_stack([request.region_x, request.region_y])
    far = ~np.isfinite(centres).all(axis=1) | (np.hypot(centres[:, 0], centres[:, 1]) > radius + reach)
    if far.any():
        i = int(np.flatnonzero(far)[0])
        raise ConfigError(f'{int(far.sum())} region point(s) are not finite or lie farther than '
                          f'the reach from the sweep disc (radius {radius:g} m), e.g. '
                          f'({request.region_x[i]!r}, {request.region_y[i]!r}): send points [m, '
                          f'tunnel frame] inside the tunnel')
    return SweepArea(centres, reach)


def main(args=None) -> int:
    return run(SimTunnel, args)


if __name__ == '__main__':
    raise SystemExit(main())
