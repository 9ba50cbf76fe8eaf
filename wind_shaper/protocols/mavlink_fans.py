"""Fan commands to an autopilot over MAVLink 2: channel map, slew limit, message builders, parser.

Pure: builds and reads pymavlink message objects, opens no socket. A fan command is a PWM
fraction u in 0..1 of a channel's [pwm_min_us, pwm_max_us] range; a fan never receives a pulse
outside [pwm(u_min), pwm(u_max)] except its safe value (stopped).

Three ways to drive outputs, chosen by ``Flavour``:

* ``ardupilot_servo``: one COMMAND_LONG ``MAV_CMD_DO_SET_SERVO`` (183) per channel, param1 =
  servo number, param2 = pulse [us]. ACKed; the output holds its value. Needs
  SERVOn_FUNCTION = 0 on the autopilot.
* ``ardupilot_rc_override``: one RC_CHANNELS_OVERRIDE with every fan channel; channels without
  a fan are set to UINT16_MAX ("ignore this field" for channels 1..8 and 9..18 alike; 0 would
  release channels 1..8 to the radio). The override times out on the autopilot, so the sender
  must refresh it (the link does, at ~10 Hz). Needs SERVOn_FUNCTION = RCINn passthrough.
* ``px4_actuator``: COMMAND_LONG ``MAV_CMD_DO_SET_ACTUATOR`` (187) (PX4 >= 1.14). Fan channel n
  is PX4's actuator n of the offboard actuator sets: param7 = set index (n - 1) // 6, param
  ((n - 1) % 6) + 1 = value, NaN for actuators not commanded. The value is -1..1 and maps
  linearly onto the channel's PWM range: -1 = pwm_min_us, +1 = pwm_max_us, so
  value = 2 (pulse - pwm_min) / (pwm_max - pwm_min) - 1. The PX4 output's PWM min/max must
  equal the map's pwm_min_us / pwm_max_us for the read-back to match.

Outputs bypass arming on both autopilots: a hardware kill path matters.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from enum import Enum
from typing import Iterable, Iterator, Mapping, Sequence

os.environ.setdefault('MAVLINK20', '1')
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

import numpy as np  # noqa: E402

from .errors import FanCommandError, ProtocolConfigError  # noqa: E402

__all__ = [
    'mavlink', 'Flavour', 'FanChannel', 'FanOutput', 'FanCommand', 'FanChannelMap',
    'SlewLimiter', 'MAV_CMD_DO_SET_SERVO', 'MAV_CMD_DO_SET_ACTUATOR', 'UINT16_MAX',
    'MAX_CHANNEL', 'servo_command_messages', 'rc_override_message', 'actuator_command_messages',
    'build_fan_messages', 'servo_output_pulses', 'applied_fractions', 'pulse_to_actuator_value',
    'actuator_value_to_pulse',
]

MAV_CMD_DO_SET_SERVO = mavlink.MAV_CMD_DO_SET_SERVO          # 183
MAV_CMD_DO_SET_ACTUATOR = mavlink.MAV_CMD_DO_SET_ACTUATOR    # 187
UINT16_MAX = 0xFFFF
MAX_CHANNEL = 16        # SERVO_OUTPUT_RAW (port 0) reads back servos 1..16
RC_OVERRIDE_CHANNELS = 18
ACTUATORS_PER_SET = 6


class Flavour(str, Enum):
    """How fan commands reach the autopilot (see the module docstring)."""

    ARDUPILOT_SERVO = 'ardupilot_servo'
    ARDUPILOT_RC_OVERRIDE = 'ardupilot_rc_override'
    PX4_ACTUATOR = 'px4_actuator'

    @classmethod
    def parse(cls, value: 'Flavour | str') -> 'Flavour':
        try:
            return cls(value)
        except ValueError:
            raise ProtocolConfigError(
                f'unknown MAVLink fan flavour {value!r}: use one of '
                f'{", ".join(f.value for f in cls)}') from None


# --------------------------------------------------------------------------------------------
# channel map

@dataclass(frozen=True)
class FanChannel:
    """One fan on one autopilot output.

    channel: servo output number, 1-based (1..16); pwm_min_us / pwm_max_us: pulse [us] at
    fraction 0 / 1; safe_us: pulse [us] that stops the fan; u_min / u_max: the fraction range a
    command is clipped into (0 <= u_min <= u_max <= 1).
    """

    name: str
    channel: int
    pwm_min_us: int = 1000
    pwm_max_us: int = 2000
    safe_us: int = 1000
    u_min: float = 0.0
    u_max: float = 1.0

    def __post_init__(self):
        if not (isinstance(self.name, str) and self.name):
            raise ProtocolConfigError(f'a fan needs a non-empty name; got {self.name!r}')
        for key in ('channel', 'pwm_min_us', 'pwm_max_us', 'safe_us'):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                if isinstance(value, float) and value.is_integer():
                    object.__setattr__(self, key, int(value))
                    continue
                raise ProtocolConfigError(f'fan {self.name!r}: {key} must be an integer; got '
                                          f'{value!r}')
            object.__setattr__(self, key, int(value))
        if not 1 <= self.channel <= MAX_CHANNEL:
            raise ProtocolConfigError(
                f'fan {self.name!r}: channel {self.channel} is outside 1..{MAX_CHANNEL}: outputs '
                f'are 1-based servo numbers and SERVO_OUTPUT_RAW reads back 1..{MAX_CHANNEL}')
        if not 1 <= self.pwm_min_us < self.pwm_max_us <= 5000:
            raise ProtocolConfigError(
                f'fan {self.name!r}: need 1 <= pwm_min_us < pwm_max_us <= 5000; got '
                f'{self.pwm_min_us}..{self.pwm_max_us} (typical ESCs: 1000..2000)')
        if not self.pwm_min_us <= self.safe_us <= self.pwm_max_us:
            raise ProtocolConfigError(
                f'fan {self.name!r}: safe_us {self.safe_us} is outside the PWM range '
                f'{self.pwm_min_us}..{self.pwm_max_us}; use the pulse that stops the fan')
        for key in ('u_min', 'u_max'):
            try:
                object.__setattr__(self, key, float(getattr(self, key)))
            except (TypeError, ValueError):
                raise ProtocolConfigError(f'fan {self.name!r}: {key} must be a number; got '
                                          f'{getattr(self, key)!r}') from None
        if not 0.0 <= self.u_min <= self.u_max <= 1.0:
            raise ProtocolConfigError(f'fan {self.name!r}: need 0 <= u_min <= u_max <= 1; got '
                                      f'u_min={self.u_min}, u_max={self.u_max}')
        if self._us_bounds()[0] > self._us_bounds()[1]:
            raise ProtocolConfigError(
                f'fan {self.name!r}: the range u {self.u_min}..{self.u_max} holds no whole '
                f'microsecond; widen it')

    @property
    def span_us(self) -> int:
        return self.pwm_max_us - self.pwm_min_us

    def _us_bounds(self) -> tuple[int, int]:
        lo = self.pwm_min_us + self.u_min * self.span_us
        hi = self.pwm_min_us + self.u_max * self.span_us
        return math.ceil(lo - 1e-9), math.floor(hi + 1e-9)

    @property
    def command_range_us(self) -> tuple[int, int]:
        """Smallest and largest pulse [us] a command can produce (the safe value aside)."""
        return self._us_bounds()

    @property
    def safe_fraction(self) -> float:
        return self.us_to_fraction(self.safe_us)

    def fraction_to_us(self, u: float) -> 'FanOutput':
        """Fraction -> pulse, clipped into [u_min, u_max]; NaN raises FanCommandError."""
        try:
            requested = float(u)
        except (TypeError, ValueError):
            raise FanCommandError(f'fan {self.name!r}: command {u!r} is not a number') from None
        if math.isnan(requested):
            raise FanCommandError(
                f'fan {self.name!r}: command is NaN; refusing to send it. Fix the controller '
                f'output, or send the safe value (go_safe) if the fan should stop')
        fraction = min(max(requested, self.u_min), self.u_max)
        clipped = fraction != requested
        lo, hi = self._us_bounds()
        pulse = min(max(int(round(self.pwm_min_us + fraction * self.span_us)), lo), hi)
        return FanOutput(self.name, self.channel, requested, fraction, pulse, clipped)

    def us_to_fraction(self, us: float) -> float:
        """Pulse [us] -> fraction of the PWM range (not clipped: reports what is applied)."""
        return (float(us) - self.pwm_min_us) / self.span_us

    def safe_output(self) -> 'FanOutput':
        safe = self.safe_fraction
        return FanOutput(self.name, self.channel, safe, safe, self.safe_us, False)


@dataclass(frozen=True)
class FanOutput:
    """What one fan is sent: the requested and applied fraction, the pulse [us], and whether
    the request was clipped into the fan's range."""

    name: str
    channel: int
    requested: float
    fraction: float
    pulse_us: int
    clipped: bool


@dataclass(frozen=True)
class FanCommand:
    """Outputs for some or all fans, in channel-map order."""

    outputs: tuple[FanOutput, ...]

    @property
    def clipped(self) -> tuple[str, ...]:
        """Names of the fans whose request was clipped into range."""
        return tuple(o.name for o in self.outputs if o.clipped)

    @property
    def pulses(self) -> dict[int, int]:
        """channel -> pulse [us]."""
        return {o.channel: o.pulse_us for o in self.outputs}

    @property
    def fractions(self) -> dict[str, float]:
        """fan name -> applied fraction."""
        return {o.name: o.fraction for o in self.outputs}

    def merged(self, newer: 'FanCommand') -> 'FanCommand':
        """This command with the outputs of ``newer`` replacing those of the same fans."""
        by_name = {o.name: o for o in self.outputs}
        by_name.update({o.name: o for o in newer.outputs})
        order = [o.name for o in self.outputs] + [o.name for o in newer.outputs
                                                  if o.name not in {p.name for p in self.outputs}]
        return FanCommand(tuple(by_name[n] for n in order))


class FanChannelMap:
    """Fan name -> autopilot output, with PWM ranges, safe values and command ranges."""

    def __init__(self, fans: Iterable[FanChannel]):
        self._fans = tuple(fans)
        if not self._fans:
            raise ProtocolConfigError('a channel map needs at least one fan')
        names = [f.name for f in self._fans]
        channels = [f.channel for f in self._fans]
        for label, values in (('fan name', names), ('channel', channels)):
            dup = sorted({v for v in values if values.count(v) > 1}, key=str)
            if dup:
                raise ProtocolConfigError(f'{label}s must be unique in a channel map; repeated: '
                                          f'{dup}')
        self._by_name = {f.name: f for f in self._fans}
        self._by_channel = {f.channel: f for f in self._fans}

    @classmethod
    def from_config(cls, fans: Mapping[str, int | Mapping], **defaults) -> 'FanChannelMap':
        """From {name: channel} or {name: {channel: ..., pwm_min_us: ..., ...}}; ``defaults``
        (pwm_min_us, pwm_max_us, safe_us, u_min, u_max) apply to every fan unless overridden."""
        if not isinstance(fans, Mapping):
            raise ProtocolConfigError(f'fan channels must be a mapping name -> channel; got '
                                      f'{type(fans).__name__}')
        out = []
        for name, spec in fans.items():
            fields = dict(defaults)
            if isinstance(spec, Mapping):
                fields.update(spec)
            else:
                fields['channel'] = spec
            try:
                out.append(FanChannel(name=str(name), **fields))
            except TypeError as exc:
                raise ProtocolConfigError(
                    f'fan {name!r}: {exc}; allowed keys are channel, pwm_min_us, pwm_max_us, '
                    f'safe_us, u_min, u_max') from None
        return cls(out)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self._fans)

    @property
    def channels(self) -> tuple[int, ...]:
        return tuple(f.channel for f in self._fans)

    def __len__(self) -> int:
        return len(self._fans)

    def __iter__(self) -> Iterator[FanChannel]:
        return iter(self._fans)

    def __getitem__(self, name: str) -> FanChannel:
        try:
            return self._by_name[name]
        except KeyError:
            raise FanCommandError(f'no fan named {name!r}; known fans: '
                                  f'{", ".join(self.names)}') from None

    def fan_on_channel(self, channel: int) -> FanChannel | None:
        return self._by_channel.get(channel)

    def command(self, fractions: Mapping[str, float] | Sequence[float]) -> FanCommand:
        """Outputs for {name: fraction} (any subset of fans) or a sequence in map order."""
        if isinstance(fractions, Mapping):
            items = list(fractions.items())
            for name, _ in items:
                self[name]  # raises for unknown names
            order = {n: i for i, n in enumerate(self.names)}
            items.sort(key=lambda kv: order[kv[0]])
        else:
            try:
                values = np.asarray(fractions, dtype=float).ravel().tolist()
            except (TypeError, ValueError):
                raise FanCommandError(f'fan commands must be numbers; got {fractions!r}') from None
            if len(values) != len(self._fans):
                raise FanCommandError(f'a command sequence needs one fraction per fan '
                                      f'({len(self._fans)}: {", ".join(self.names)}); got '
                                      f'{len(values)}')
            items = list(zip(self.names, values))
        return FanCommand(tuple(self._by_name[n].fraction_to_us(u) for n, u in items))

    def safe_command(self) -> FanCommand:
        """Every fan at its safe pulse."""
        return FanCommand(tuple(f.safe_output() for f in self._fans))

    def fractions_from_pulses(self, pulses: Mapping[int, int]) -> dict[str, float]:
        """{channel: pulse [us]} -> {fan name: fraction} for the mapped channels present."""
        return {f.name: f.us_to_fraction(pulses[f.channel]) for f in self._fans
                if f.channel in pulses}

    def __repr__(self) -> str:
        inner = ', '.join(f'{f.name}->ch{f.channel}' for f in self._fans)
        return f'FanChannelMap({inner})'


# --------------------------------------------------------------------------------------------
# slew limit

class SlewLimiter:
    """Limits how fast commands move: |u(t2) - u(t1)| <= max_rate * (t2 - t1).

    max_rate_per_s [fraction/s] (inf = no limit); times [s] from a monotonic clock; works on a
    scalar or an array of fans. Without ``initial`` the first step passes its target through.
    A clock that goes backwards counts as no time passing.
    """

    def __init__(self, max_rate_per_s: float, initial: float | Sequence[float] | None = None):
        rate = float(max_rate_per_s)
        if not rate > 0:
            raise ProtocolConfigError(f'max_rate_per_s must be > 0 fraction/s (inf for no limit); '
                                      f'got {max_rate_per_s!r}')
        self.max_rate_per_s = rate
        self.reset(initial)

    def reset(self, value: float | Sequence[float] | None = None) -> None:
        """Forget the time; start from ``value`` (None: the next target passes through)."""
        self._value = None if value is None else self._checked(value)
        self._time: float | None = None

    @property
    def value(self):
        return None if self._value is None else self._out(self._value)

    def step(self, now: float, target):
        """The command at time ``now`` [s] moving toward ``target`` [fraction]."""
        goal = self._checked(target)
        if self._value is None:
            self._value = goal
        else:
            if goal.shape != self._value.shape:
                raise FanCommandError(f'target has shape {goal.shape} but the limiter holds '
                                      f'{self._value.shape}; reset() it when the fan set changes')
            dt = 0.0 if self._time is None else max(0.0, float(now) - self._time)
            if math.isinf(self.max_rate_per_s):
                self._value = goal
            else:
                limit = self.max_rate_per_s * dt
                self._value = self._value + np.clip(goal - self._value, -limit, limit)
        self._time = float(now)
        return self._out(self._value)

    @staticmethod
    def _checked(value) -> np.ndarray:
        arr = np.array(value, dtype=float)
        if np.any(np.isnan(arr)):
            raise FanCommandError(f'slew limiter target contains NaN: {arr.tolist()}')
        return arr

    def _out(self, arr: np.ndarray):
        return float(arr) if arr.ndim == 0 else arr.copy()

    def __repr__(self) -> str:
        return f'SlewLimiter(max_rate_per_s={self.max_rate_per_s})'


# --------------------------------------------------------------------------------------------
# message builders

def _command_long(command: int, params: Sequence[float], target_system: int,
                  target_component: int) -> 'mavlink.MAVLink_command_long_message':
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(target_system, target_component, command, 0, *p)


def servo_command_messages(pulses: Mapping[int, int], target_system: int = 1,
                           target_component: int = 1) -> list:
    """One COMMAND_LONG MAV_CMD_DO_SET_SERVO per channel: param1 servo number, param2 pulse [us]."""
    return [_command_long(MAV_CMD_DO_SET_SERVO, (ch, us), target_system, target_component)
            for ch, us in sorted(pulses.items())]


def rc_override_message(pulses: Mapping[int, int], target_system: int = 1,
                        target_component: int = 1):
    """One RC_CHANNELS_OVERRIDE: the given channels [us], every other one UINT16_MAX (ignore)."""
    chans = [UINT16_MAX] * RC_OVERRIDE_CHANNELS
    for ch, us in pulses.items():
        if not 1 <= ch <= RC_OVERRIDE_CHANNELS:
            raise ProtocolConfigError(f'RC override carries channels 1..{RC_OVERRIDE_CHANNELS}; '
                                      f'got {ch}')
        if not 1 <= us < UINT16_MAX - 1:
            raise FanCommandError(f'RC override pulse {us} on channel {ch} would read as a '
                                  f'release/ignore marker; pulses must be 1..65533 us')
        chans[ch - 1] = int(us)
    return mavlink.MAVLink_rc_channels_override_message(target_system, target_component, *chans)


def actuator_command_messages(values: Mapping[int, float], target_system: int = 1,
                              target_component: int = 1) -> list:
    """COMMAND_LONG MAV_CMD_DO_SET_ACTUATOR for {actuator number (1-based): value -1..1}.

    One message per set of six actuators: param7 = set index (actuator n is in set
    (n - 1) // 6, slot (n - 1) % 6); slots not commanded are NaN (PX4: leave unchanged).
    """
    sets: dict[int, list[float]] = {}
    for n, value in values.items():
        if n < 1:
            raise ProtocolConfigError(f'actuator numbers are 1-based; got {n}')
        v = float(value)
        if not -1.0 <= v <= 1.0:
            raise FanCommandError(f'actuator {n} value {v} is outside -1..1')
        index, slot = divmod(n - 1, ACTUATORS_PER_SET)
        sets.setdefault(index, [math.nan] * ACTUATORS_PER_SET)[slot] = v
    return [_command_long(MAV_CMD_DO_SET_ACTUATOR, (*slots, float(index)), target_system,
                          target_component) for index, slots in sorted(sets.items())]


def pulse_to_actuator_value(fan: FanChannel, pulse_us: int) -> float:
    """Pulse [us] -> DO_SET_ACTUATOR value: -1 at pwm_min_us, +1 at pwm_max_us."""
    return min(1.0, max(-1.0, 2.0 * (pulse_us - fan.pwm_min_us) / fan.span_us - 1.0))


def actuator_value_to_pulse(value: float, pwm_min_us: int = 1000, pwm_max_us: int = 2000) -> int:
    """DO_SET_ACTUATOR value -1..1 -> pulse [us] (what an autopilot applies)."""
    return int(round(pwm_min_us + (float(value) + 1.0) / 2.0 * (pwm_max_us - pwm_min_us)))


def build_fan_messages(flavour: Flavour | str, command: FanCommand, channel_map: FanChannelMap,
                       target_system: int = 1, target_component: int = 1) -> list:
    """The messages that apply ``command`` with the given flavour.

    For ``ardupilot_rc_override`` pass the full state (every fan): channels left out are sent as
    "ignore" and keep whatever the override held before, until it times out.
    """
    flavour = Flavour.parse(flavour)
    if flavour is Flavour.ARDUPILOT_SERVO:
        return servo_command_messages(command.pulses, target_system, target_component)
    if flavour is Flavour.ARDUPILOT_RC_OVERRIDE:
        return [rc_override_message(command.pulses, target_system, target_component)]
    values = {o.channel: pulse_to_actuator_value(channel_map[o.name], o.pulse_us)
              for o in command.outputs}
    return actuator_command_messages(values, target_system, target_component)


# --------------------------------------------------------------------------------------------
# parser

def servo_output_pulses(msg) -> dict[int, int]:
    """SERVO_OUTPUT_RAW -> {channel: pulse [us]}; channel = 16 * port + servo index.

    Fields at 0 or UINT16_MAX (output not present) are left out.
    """
    if msg.get_type() != 'SERVO_OUTPUT_RAW':
        raise ProtocolConfigError(f'expected a SERVO_OUTPUT_RAW message; got {msg.get_type()}')
    base = 16 * int(msg.port)
    out = {}
    for k in range(1, 17):
        us = getattr(msg, f'servo{k}_raw', 0)
        if us not in (0, UINT16_MAX):
            out[base + k] = int(us)
    return out


def applied_fractions(msg, channel_map: FanChannelMap) -> dict[str, float]:
    """SERVO_OUTPUT_RAW -> {fan name: applied fraction} for the mapped channels it carries."""
    return channel_map.fractions_from_pulses(servo_output_pulses(msg))
