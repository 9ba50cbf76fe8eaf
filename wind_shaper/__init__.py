"""wind_shaper: online-learning airflow shaping for multi-fan wind tunnels."""

__version__ = '0.2.0'
