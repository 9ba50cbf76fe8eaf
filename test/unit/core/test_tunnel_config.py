"""core.geometry: a damaged tunnel config ends in a ConfigError that names the key and says
what to do, never in another kind of exception, and a config that would build millions of fans
or key points is refused before any array is made (found by the long fuzz run)."""
import pytest
import yaml

from wind_shaper.core.config import load_geometry
from wind_shaper.core.errors import ConfigError
from wind_shaper.core.geometry import TunnelGeometry

SHIPPED = {'fans': {'layout': 'paper_rig', 'hex_radius': 0.25, 'disabled': []},
           'key_points': {'kind': 'disc', 'radius': 0.30, 'spacing': 0.03},
           'wall_radius': 0.40, 'plate_side': 0.20, 'sweep_radius': 0.34}


def damaged(path, value):
    """The shipped tunnel section with the entry at ``path`` (a tuple of keys) set to ``value``."""
    doc = yaml.safe_load(yaml.safe_dump(SHIPPED))
    if not path:
        return value
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return doc


@pytest.mark.parametrize('path, value, says', [
    ((), [1, 2], 'the tunnel section must be a mapping'),
    ((), 'paper_rig', 'the tunnel section must be a mapping'),
    (('fans',), 'abc', 'tunnel.fans must be a mapping'),
    (('fans',), [['name', 'x']], 'tunnel.fans must be a mapping'),
    (('fans', 'disabled'), 5, 'tunnel.fans.disabled must be a list'),
    (('fans', 'disabled'), [[1, 2]], 'tunnel.fans.disabled must be a list'),
    (('fans', 'hex_radius'), 'wide', 'tunnel.fans.hex_radius must be a number'),
    (('fans', 'hex_radius'), float('nan'), 'finite positive'),
    (('fans', 'hex_radius'), 10 ** 400, 'finite positive'),
    (('fans', 'layout'), ['grid'], 'unknown fan layout'),
    (('fans',), {'fans': 'LM1'}, 'tunnel.fans.fans must be a list'),
    (('fans',), {'fans': ['LM1']}, 'tunnel.fans.fans[0] must be a mapping'),
    (('fans',), {'fans': [{'name': 'A', 'x': 'left', 'y': 0}]}, "fan 'A': x must be a number"),
    (('fans',), {'fans': [{'name': ['A'], 'x': 0, 'y': 0}]}, 'a fan name must be'),
    (('fans',), {'fans': [{1: 'A'}]}, 'keys must be names'),
    (('fans',), {'fans': [{'name': 'A', 'x': 0, 'y': 0, 'enabled': 'maybe'}]}, 'true or false'),
    (('fans',), {'layout': 'grid', 'rows': 'six', 'cols': 6, 'pitch': 0.08},
     'tunnel.fans.rows must be a number'),
    (('fans',), {'layout': 'grid', 'rows': 2.5, 'cols': 6, 'pitch': 0.08}, 'whole number'),
    (('fans',), {'layout': 'grid', 'rows': 100_000, 'cols': 100_000, 'pitch': 0.08},
     'more than 10000 fans'),
    (('key_points',), 7, 'tunnel.key_points must be a mapping'),
    (('key_points', 'radius'), 'big', 'key_points.radius must be a number'),
    (('key_points', 'spacing'), float('nan'), 'finite positive'),
    (('key_points', 'spacing'), 1e-9, 'key points'),
    (('key_points',), {'kind': 'rect', 'half_width': 0.3, 'half_height': 0.3, 'nx': 1e9, 'ny': 5},
     'more than 200000'),
    (('key_points',), {'kind': 'disc', 3: 4}, 'keys must be names'),
    (('key_points',), {'kind': 'disc', 'radius': 0.3, 'spacing': 0.03, 'centre': 0},
     'bad key_points config'),
    (('wall_radius',), [0.4], 'tunnel.wall_radius must be a number'),
    (('sweep_radius',), float('inf'), 'finite positive'),
])
def test_a_damaged_tunnel_section_is_refused_with_the_key_named(path, value, says):
    with pytest.raises(ConfigError) as refused:
        TunnelGeometry.from_config(damaged(path, value))
    assert says in str(refused.value)
    assert len(str(refused.value)) < 400


def test_a_damaged_tunnel_file_is_refused_as_a_config_error(tmp_path):
    path = tmp_path / 'tunnel.yaml'
    path.write_text('tunnel:\n  fans: [1, 2, 3]\n')
    with pytest.raises(ConfigError, match='tunnel.fans must be a mapping'):
        load_geometry(path)


def test_the_shipped_forms_still_build():
    assert len(TunnelGeometry.from_config(SHIPPED).key_points) == 317
    grid = TunnelGeometry.from_config({'fans': {'layout': 'grid', 'rows': 36, 'cols': 36,
                                                'pitch': 0.08},
                                       'key_points': {'kind': 'rect', 'half_width': 1.4,
                                                      'half_height': 1.4, 'nx': 30, 'ny': 30}})
    assert grid.fans.n_fans == 1296 and len(grid.key_points) == 900
    listed = TunnelGeometry.from_config({'fans': {'fans': [{'name': 'A', 'x': 0, 'y': 0.1},
                                                           {'name': 'B', 'x': 0.1, 'y': 0}],
                                                  'disabled': ['B']}})
    assert listed.fans.enabled.tolist() == [True, False]
