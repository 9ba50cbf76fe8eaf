"""Parameters declared from a dataclass: defaults, descriptors, overrides, validation."""
from dataclasses import dataclass

import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.parameter import Parameter  # noqa: E402

from wind_shaper.core.errors import ConfigError  # noqa: E402
from wind_shaper.ros.params import declare_parameters, param  # noqa: E402

pytestmark = pytest.mark.ros


@dataclass(frozen=True)
class Example:
    rate_hz: float = param(100.0, 'publish rate [Hz]', low=1.0, high=1000.0)
    port: int = param(49152, 'UDP port', low=1, high=65535)
    host: str = param('127.0.0.1', 'sensor address')
    channels: tuple = param((1, 2, 3), 'servo channels', array_of=int)
    enabled: bool = param(True, 'switch')

    def __post_init__(self):
        if not self.host:
            raise ConfigError('host must not be empty')


@pytest.fixture
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_defaults_descriptors_and_overrides(ros):
    node = rclpy.create_node('p1', parameter_overrides=[Parameter('port', value=5000)])
    try:
        cfg = declare_parameters(node, Example)
        assert cfg == Example(port=5000)
        desc = node.describe_parameter('rate_hz')
        assert desc.read_only and desc.floating_point_range[0].to_value == 1000.0
        assert 'Hz' in desc.description
        assert node.describe_parameter('port').integer_range[0].to_value == 65535
    finally:
        node.destroy_node()


def test_out_of_range_and_invalid_values_are_refused(ros):
    node = rclpy.create_node('p2', parameter_overrides=[Parameter('rate_hz', value=5000.0)])
    try:
        with pytest.raises(ConfigError, match="'rate_hz'"):
            declare_parameters(node, Example)
    finally:
        node.destroy_node()
    node = rclpy.create_node('p3', parameter_overrides=[Parameter('host', value='')])
    try:
        with pytest.raises(ConfigError, match='host must not be empty'):
            declare_parameters(node, Example)
    finally:
        node.destroy_node()


def test_wrong_type_names_the_parameter(ros):
    node = rclpy.create_node('p4', parameter_overrides=[Parameter('host', value=12)])
    try:
        with pytest.raises(ConfigError, match="'host'"):
            declare_parameters(node, Example)
    finally:
        node.destroy_node()
