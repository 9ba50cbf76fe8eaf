"""Install script for wind_shaper (ament_python layout, also a plain pip package)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'wind_shaper'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, PACKAGE + '.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*')),
    ],
    package_data={PACKAGE: ['data/*.yaml']},
    install_requires=['setuptools', 'numpy', 'scipy', 'pyyaml', 'matplotlib'],
    zip_safe=True,
    maintainer='wind_shaper developers',
    description='Online-learning airflow shaping for multi-fan wind tunnels',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'wind-shaper = wind_shaper.cli.main:main',
        ],
    },
)
