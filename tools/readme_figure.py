"""Draws docs/field_before_after.png, the README's picture: the simulated tunnel's field with every
fan at the same command (before shaping) and after a few iterations of the shaping loop toward the
soaring robot's parabolic profile, beside the target. In-process (no ROS), the way
`wind-shaper shape --sim --target parabolic --u0 0.5` runs; the maps are the field estimates the
loop measured, drawn like the run report's field_maps.png (wind_shaper/report/run_report.py).

    .venv/bin/python tools/readme_figure.py [--iterations 4] [--seed 0] [--out docs/field_before_after.png]
"""
import argparse

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402

from wind_shaper.app import Setup, shape_on_sim  # noqa: E402
from wind_shaper.report.run_report import draw_fans  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--iterations', type=int, default=4, help='updates after the first sweep')
    ap.add_argument('--seed', type=int, default=0, help='simulator seed')
    ap.add_argument('--out', default='docs/field_before_after.png', help='PNG to write')
    args = ap.parse_args(argv)

    setup = Setup.load()
    records, target = shape_on_sim(setup, 'parabolic', iterations=args.iterations, seed=args.seed, u0=0.5)
    geometry = setup.geometry
    kp = geometry.key_points
    tri = mtri.Triangulation(kp[:, 0], kp[:, 1])
    goal = target.values(kp)
    first, last = records[0], records[-1]
    levels = np.linspace(min(goal.min(), first.estimate.mean.min(), last.estimate.mean.min()),
                         max(goal.max(), first.estimate.mean.max(), last.estimate.mean.max()), 21)
    panels = (
        (first.estimate.mean, f'before: every fan at {100 * first.pwm[0]:.0f} % PWM\n'
                              f'RMSE to target {np.sqrt(first.error):.2f} N'),
        (last.estimate.mean, f'after {last.k} iterations\nRMSE to target {np.sqrt(last.error):.2f} N'),
        (goal, 'target: parabolic profile\n2.25 + 30 (x² + y²) N'),
    )
    fig, axes = plt.subplots(1, 3, figsize=(12.5, 3.8))
    for ax, (values, title) in zip(axes, panels):
        cs = ax.tricontourf(tri, values, levels=levels, cmap='viridis', extend='both')
        draw_fans(ax, geometry)
        ax.set_title(title, fontsize=9)
    fig.colorbar(cs, ax=axes, label='vertical force on the plate [N]', shrink=0.9, format='%.1f')
    fig.savefig(args.out, dpi=80, bbox_inches='tight')
    for rec in records:
        print(f'k={rec.k}  RMSE to target {np.sqrt(rec.error):.3f} N  PWM % '
              + ' '.join(f'{100 * u:.0f}' for u in rec.pwm))
    print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
