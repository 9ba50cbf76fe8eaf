"""Install script for wind_shaper (ament_python layout, also a plain pip package)."""
import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'wind_shaper'

setup(
    name=PACKAGE,
    version='0.2.0',
    packages=find_packages(include=[PACKAGE, PACKAGE + '.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', [f for f in glob('config/*') if os.path.isfile(f)]),
        ('share/' + PACKAGE + '/config/rviz', glob('config/rviz/*.rviz')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    package_data={PACKAGE: ['data/*.yaml']},
    install_requires=['setuptools', 'numpy', 'scipy', 'pyyaml', 'matplotlib', 'pymavlink', 'rosbags', 'pysindy', 'threadpoolctl', 'foxglove-sdk'],
    zip_safe=True,
    maintainer='wind_shaper developers',
    description='Online-learning airflow shaping for multi-fan wind tunnels',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'wind-shaper = wind_shaper.cli.main:main',
            # one process per node: `ros2 run wind_shaper <node>`
            'fan_output = wind_shaper.nodes.fan_output:main',
            'force_sensor = wind_shaper.nodes.force_sensor:main',
            'mocap_relay = wind_shaper.nodes.mocap_relay:main',
            'field_estimator = wind_shaper.nodes.field_estimator:main',
            'coordinator = wind_shaper.nodes.coordinator:main',
            'sim_tunnel = wind_shaper.nodes.sim_tunnel:main',
            'live_view = wind_shaper.nodes.live_view:main',
        ],
    },
)
