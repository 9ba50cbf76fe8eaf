"""`wind-shaper` command line: shape a multi-fan wind tunnel's airflow to a target profile,
commission its prior and study its model (each command's own --help says more).

The commands are a thin argument layer over ``wind_shaper.app``."""
from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

import numpy as np

from ..core.bias import BIAS_MODES
from ..core.errors import WindShaperError


def _common(p):
    p.add_argument('--config', type=Path, default=None,
                   help='config folder with tunnel.yaml, shaping.yaml, sim.yaml, model.yaml '
                        '(default: the shipped one)')
    p.add_argument('--disable', action='append', default=[], metavar='FAN',
                   help='run with this fan disabled (held at 0); repeat for more')
    p.add_argument('--seed', type=int, default=0, help='simulator seed (sweeps and noise)')


def _cmd_shape(args) -> int:
    from ..app import Setup, format_iteration, hidden_effects, shaping_loop_on_sim
    from ..model import load_plugins
    from ..report.run_report import write_report
    if not args.sim:
        print('wind-shaper shape runs in-process on the simulated tunnel only: add --sim. '
              'For the rig, start the node graph (see README).', file=sys.stderr)
        return 2
    load_plugins(args.plugin)  # and WIND_SHAPER_PLUGINS: terms a model file names, sim effects
    setup = Setup.load(args.config, args.disable)
    effects = hidden_effects(args.hidden)
    sim = setup.make_sim(seed=args.seed, effects=effects)  # checks the effects (fans named) first
    model = setup.load_model(args.model) if args.model else None
    names = setup.geometry.fans.names
    rule = {}
    if args.gain is not None:
        rule['gain'] = args.gain
    if args.method is not None:
        rule['method'] = args.method
    print(f'target {args.target}; {setup.geometry.fans.n_fans} fans '
          f'({", ".join(n for n, e in zip(names, setup.geometry.fans.enabled) if not e) or "none"} '
          f'disabled); {len(setup.geometry.key_points)} key points'
          + (f'; hidden effects: {", ".join(args.hidden)}' if args.hidden else ''))
    t0 = time.perf_counter()
    from .model import _u0
    u0 = _u0(args.u0)
    loop, target = shaping_loop_on_sim(setup, args.target, seed=args.seed, model=model, sim=sim,
                                       u0=u0, rule_overrides=rule or None, model_path=args.model,
                                       bias_zero=args.bias_zero)
    note = setup.prior_maps(args.model)[1] if args.model else ''
    if note:   # the model file's maps were made at other key points
        print(f'note: {note}')
    if loop.warm is not None:
        print(loop.warm.text())
        for note in loop.warm.notes:
            print(f'note: {note}')

    def show(rec):
        print(format_iteration(rec, names), flush=True)
        check = rec.info.get('warm_start', {}).get('check_text')
        if check:
            print(('WARNING: ' if rec.info['warm_start']['check']['mismatch'] else '') + check)

    n = setup.shaping.iterations if args.iterations is None else args.iterations
    records = loop.run(n, show)
    out = args.out or Path('reports') / time.strftime('shape-%Y%m%d-%H%M%S')
    time_used = loop.tunnel_time()
    meta = {'target': target.describe(), 'target_spec': args.target, 'seed': args.seed,
            'disabled': args.disable, 'hidden_effects': [e.spec() for e in effects],
            'model': repr(model or setup.load_model()),
            'config_dir': str(setup.config_dir), 'update': {**dict(setup.shaping.update or {}), **rule},
            'warm_start': None if loop.warm is None else loop.warm.to_json(),
            'tunnel_time_s': time_used, 'wall_time_s': round(time.perf_counter() - t0, 3)}
    write_report(out, records, setup.geometry, meta, u_max=setup.shaping.u_max)
    first, last = records[0], records[-1]
    if first.true_error is not None:
        print(f'true-field RMSE {np.sqrt(first.true_error):.3f} N -> {np.sqrt(last.true_error):.3f} N '
              f'after {last.k} iteration{"" if last.k == 1 else "s"}')
    print(f'tunnel time: {time_used["plate_total_s"]:.0f} s of sweeping + '
          f'{time_used["settle_total_s"]:.0f} s of fan settling over {len(records)} '
          f'sweep{"" if len(records) == 1 else "s"}')
    print(f'report: {out}/ (run.json, field_maps.png, error.png, pwm.png)')
    return 0


def _cmd_calibrate(args) -> int:
    from ..app import Setup, calibrate, save_fit
    if int(args.sim) + int(bool(args.data)) + int(args.held) != 1:
        print('wind-shaper calibrate needs one source: --data RUN_OR_BAG (moving-plate sweeps at '
              'varied commands, e.g. from `wind-shaper collect --design lhs:6+level --out NAME`), --held '
              '(the held-plate batch, guided through the node graph) or --sim (that batch on the '
              'built-in simulated tunnel, in-process; with --design lhs:6+level designed sweeps there '
              'instead)', file=sys.stderr)
        return 2
    if args.design and not args.sim:
        print('wind-shaper calibrate: --design goes with --sim (the simulated tunnel, in-process); on '
              'the rig record the design with `wind-shaper collect --design SPEC --out NAME`, then '
              '`wind-shaper calibrate --data runs/NAME`', file=sys.stderr)
        return 2
    setup = Setup.load(args.config, args.disable)
    if args.data:
        return _calibrate_from_data(setup, args)
    if args.held:
        from .held import run_held
        return run_held(setup, args)
    if args.design:
        return _calibrate_on_sim_from_design(setup, args)
    fit = calibrate(setup.make_sim(seed=args.seed), setup.geometry.fans)
    out = args.out or setup.model_path
    save_fit(out, fit, source=f'simulated tunnel, seed {args.seed}')
    print(f'fitted {fit.model!r}\nRMSE {fit.rmse:.4f} N on {fit.n} samples; written to {out}')
    return 0


def _calibrate_from_data(setup, args) -> int:
    from ..workbench.calibrate import calibrate_default_prior, calibrate_from_sweeps
    from ..workbench.data import load_sweeps
    from ..workbench.errors import WiringSweepsOnly
    fans = setup.geometry.fans
    data = load_sweeps(args.data, fans.names)
    try:
        cal = (calibrate_from_sweeps(data, setup.load_model(args.model)) if args.model
               else calibrate_default_prior(data, fans))
    except WiringSweepsOnly as only:
        return _report_wiring_only(only)
    return _report_calibration(cal, args.out or Path('models') / f'{Path(args.data).name or "calibrated"}.yaml',
                               setup)


def _calibrate_on_sim_from_design(setup, args) -> int:
    """``calibrate --sim --design SPEC``: the designed sweeps on the simulated tunnel, in-process
    (as `collect --design SPEC` and `calibrate --data` would through the graph), then the fit."""
    from ..experiment.design import DesignError
    from ..workbench.calibrate import commission_from_design
    from ..workbench.errors import WiringSweepsOnly
    try:
        cal = commission_from_design(setup.make_sim(seed=args.seed), args.design, setup.shaping.u_min,
                                     setup.shaping.u_max, n_samples=setup.shaping.samples_per_sweep,
                                     seed=args.seed,
                                     model=setup.load_model(args.model) if args.model else None)
    except DesignError as exc:
        print(f'wind-shaper calibrate: {exc}', file=sys.stderr)
        return 2
    except WiringSweepsOnly as only:
        return _report_wiring_only(only)
    return _report_calibration(cal, args.out or setup.model_path, setup)


def _report_wiring_only(only) -> int:
    """Sweeps of the single-off design: the wiring check's verdict, no model file. 0 when the
    wiring is as configured, 1 when a misrouting is named, not settled, or could not be judged."""
    verdict = only.wiring
    doubt = not verdict.checked or verdict.swapped is not None or bool(verdict.why)
    print(verdict.text, file=sys.stderr if doubt else sys.stdout)
    print(f'no model file written: {only}')
    return 1 if doubt else 0


def _report_calibration(cal, out, setup) -> int:
    """Write the calibrated model file to ``out`` (with the sweeps' field maps at the setup's key
    points, for the update rule's fit) and print the fit, its grades and the next step."""
    from ..workbench.calibrate import keep_commissioning_maps, save_calibration
    save_calibration(out, cal)
    kept = keep_commissioning_maps(out, cal.data, setup.shaping.make_estimator(cal.model),
                                   setup.geometry.key_points) if cal.data else 0
    print(f'fitted {cal.model!r} on {cal.n_sweeps} sweeps of {cal.source}')
    print(f'RMSE {cal.fit.rmse:.4f} N on all sweeps; {cal.heldout_rmse:.4f} N on the held-out sweeps '
          f'({", ".join(cal.held_out)}) of a fit on the others')
    if cal.compared:
        chosen, other = cal.compared
        print(f'kept {chosen[0]} (held-out RMSE {chosen[1]:.4f} N) over {other[0]} ({other[1]:.4f} N)')
    for name, value, std in zip(cal.fit.names, cal.fit.theta, cal.fit.theta_std):
        print(f'  {cal.model.display_name(name):<32} {value:10.4f} +- {std:.4f}')
    print(f'{kept} of the sweeps kept as field maps for every run\'s update, its first step and '
          f'later steps near them (the sweeps with fans running that cover the key points)')
    print(f'written to {out}; load it into the running coordinator with `wind-shaper set-model {out}`')
    if cal.wiring is not None:
        swapped = cal.wiring.checked and cal.wiring.swapped is not None
        print(cal.wiring.text, file=sys.stderr if swapped else sys.stdout)
    return 0


def _cmd_targets_template(args) -> int:
    from ..app import Setup
    from ..control import write_template_csv
    setup = Setup.load(args.config, args.disable)
    kp = setup.geometry.key_points
    target = setup.make_target(args.start)
    if args.out.exists() and not args.force:
        print(f'wind-shaper: error: {args.out} exists; choose another file or add --force to '
              f'overwrite it', file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_template_csv(args.out, kp, target.values(kp))
    print(f'wrote {args.out}: {len(kp)} key points of {setup.config_dir / "tunnel.yaml"} with the '
          f'forces of {target.describe()!r}; edit the force column [N], then use '
          f'--target csv:{args.out}')
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='wind-shaper', description=__doc__.split('\n\n')[0].replace('\n', ' '))
    parser.add_argument('--namespace', default=None, metavar='NS',
                        help='the ROS namespace of the node graph (default: $WIND_SHAPER_NAMESPACE, '
                             'else /): `up` starts its nodes in it and every other command talks '
                             'to the graph there, so two tunnels share a ROS domain; e.g. '
                             '`wind-shaper --namespace tunnel_b up --sim`')
    sub = parser.add_subparsers(dest='command', required=True)

    p = sub.add_parser('shape', help='run the online-learning loop on the simulated tunnel (update '
                                     'rule from shaping.yaml: adaptive by default, --method paper '
                                     'for Algorithm 1)')
    _common(p)
    p.add_argument('--sim', action='store_true', help='use the built-in simulated tunnel')
    p.add_argument('--target', default='parabolic',
                   help='uniform[:F] | gaussian[@FAN] | parabolic | expr:<f(x,y)> | csv:<file>')
    p.add_argument('--iterations', type=int, default=None, help='updates (default: shaping.yaml)')
    p.add_argument('--gain', type=float, default=None, help='step gain (paper: 0.8)')
    p.add_argument('--method', choices=('adaptive', 'paper'), default=None,
                   help='update rule (default: shaping.yaml); paper = Algorithm 1 exactly')
    p.add_argument('--model', type=Path, default=None, help='model file (default: config/model.yaml)')
    p.add_argument('--u0', default=None, metavar='warm|COMMAND',
                   help="starting commands: 'warm' (the prior's optimum) or one command for every "
                        'fan, e.g. 0.5 (default: shaping.yaml u0)')
    p.add_argument('--hidden', action='append', default=[], metavar='EFFECT[:k=v,...]',
                   help='switch on a simulator hidden effect, e.g. weak_fan:fan=HM2,gain=0.8 or '
                        'tilted_fan:fan=LM2,shift=0.04/0 (as `model diagnose --sim --hidden`); repeat '
                        'for more')
    p.add_argument('--plugin', action='append', default=[], metavar='FILE.py|MODULE',
                   help='import your own model terms (or simulator effects) first, e.g. for a model '
                        'file naming a term kind of yours; repeat for more (or list them in '
                        'WIND_SHAPER_PLUGINS)')
    p.add_argument('--bias-zero', choices=BIAS_MODES, default='never',
                   help="every_sweep: bias the force sensor before every sweep with every fan off "
                        "(as the coordinator's bias_zero; against a drifting zero, e.g. --hidden "
                        "sensor_zero_drift); counts a spin-down more per sweep (default: never)")
    p.add_argument('--out', type=Path, default=None, help='report folder (default: reports/shape-<time>)')
    p.set_defaults(func=_cmd_shape)

    p = sub.add_parser('calibrate', help='fit the prior: from recorded moving-plate sweeps (--data) '
                                         'or the held-plate batch on the simulated tunnel (--sim)')
    _common(p)
    p.add_argument('--data', type=Path, default=None, metavar='RUN_OR_BAG',
                   help='sweeps at varied commands: an experiment folder or bag of `wind-shaper '
                        'collect`, a run folder or a shape report (sweeps of the single-off design '
                        'check the wiring only, and write no model file)')
    p.add_argument('--model', type=Path, default=None,
                   help='with --data or --sim --design: the model whose free parameters are fitted '
                        '(default: the paper\'s prior, and where the whole field lands if that '
                        'predicts the held-out sweeps better)')
    p.add_argument('--sim', action='store_true', help='collect the held-plate batch on the simulated '
                                                      'tunnel and fit the paper\'s prior to it')
    p.add_argument('--design', default=None, metavar='SPEC',
                   help='with --sim: sweep the simulated tunnel at a designed experiment instead (lhs:N[+level], '
                        'single-off, or a CSV/YAML design, as `collect --design`) and fit the prior to '
                        'those sweeps, every fan running; the recommended commissioning (lhs:6+level)')
    p.add_argument('--out', type=Path, default=None,
                   help='model file to write (default: models/<data or batch name>.yaml with '
                        '--data or --held, config/model.yaml with --sim)')
    from .held import add_arguments as held_arguments
    held_arguments(p)
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser('targets', help='target profiles: write a CSV template to edit by hand')
    targets = p.add_subparsers(dest='targets_command', required=True, metavar='{template}')
    p = targets.add_parser('template', help='write x,y,force for every key point of the tunnel '
                                            '(forces from --start), for --target csv:FILE')
    _common(p)
    p.add_argument('out', type=Path, help='CSV file to write')
    p.add_argument('--start', default='uniform', metavar='TARGET',
                   help='profile whose forces fill the force column (default: uniform, 2.5 N); '
                        'any --target form')
    p.add_argument('--force', action='store_true', help='overwrite an existing file')
    p.set_defaults(func=_cmd_targets_template)

    # Subcommands that talk to the ROS graph live in their own modules (rclpy imported lazily).
    for module in _GRAPH_COMMANDS:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue  # that part of the graph is not built yet
        mod.register(sub)
    return parser


#: Modules with a ``register(subparsers)`` adding graph commands: up (graph.py), iterate /
#: status / cancel (service.py), collect (collect.py), record / replay (bag.py).
_GRAPH_COMMANDS = ('wind_shaper.cli.graph', 'wind_shaper.cli.service', 'wind_shaper.cli.collect',
                   'wind_shaper.cli.bag', 'wind_shaper.cli.model')


def main(argv=None) -> int:
    import os

    from ..ros.names import NAMESPACE_ENV, check_namespace
    args = build_parser().parse_args(argv)
    try:
        ns = check_namespace(args.namespace if args.namespace is not None
                             else os.environ.get(NAMESPACE_ENV, ''))
    except ValueError as exc:
        where = '--namespace' if args.namespace is not None else f'${NAMESPACE_ENV}'
        print(f'wind-shaper: error: {where}: {exc}', file=sys.stderr)
        return 2
    if args.namespace is not None:   # every command, and the nodes `up` starts, read it there
        os.environ[NAMESPACE_ENV] = ns
    try:
        return args.func(args)
    except WindShaperError as exc:
        print(f'wind-shaper: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('wind-shaper: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
