"""`wind-shaper model fit | compare | diagnose | add`: the model workbench on the command line.

A thin argument layer over ``wind_shaper.workbench.commands``. Data come from the simulated
tunnel (``--sim``, with ``--hidden`` effects switched on), or from recorded sweeps (``--data``: a
rosbag2 bag, a coordinator run folder or a ``wind-shaper shape`` report folder). Every command
writes a report folder (report.html, report.md, PNGs, summary.json).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from ..core.errors import WindShaperError

REFERENCE_FILE = 'reference.yaml'
SUGGESTED_DESIGN = 'suggested_design.csv'


def _load_plugins(specs) -> list:
    """Import each ``--plugin`` (a Python file or a module name) and those listed in
    WIND_SHAPER_PLUGINS (``model.plugins``); return the candidate families they offer (a
    module-level ``FAMILIES`` list)."""
    from ..model import load_plugins, plugin_families
    return plugin_families(load_plugins(specs))


def _setup(args):
    from ..app import Setup
    return Setup.load(args.config, args.disable)


def _hidden(args):
    from ..app import hidden_effects
    return hidden_effects(args.hidden)


def _sim(setup, args, seed=None):
    return setup.make_sim(seed=args.seed if seed is None else seed, effects=_hidden(args))


def _data(setup, args):
    from ..workbench.commands import simulated_sweeps
    from ..workbench.data import load_sweeps
    if args.sim == bool(args.data):
        raise WindShaperError('give one source of sweeps: --sim (the simulated tunnel) or --data PATH '
                              '(a bag, a run folder or a shape report)'
                              + (', not both' if args.sim else ''))
    if args.sim:
        data = simulated_sweeps(_sim(setup, args), args.sweeps, seed=args.seed, n_samples=args.samples)
    else:
        if args.hidden:
            raise WindShaperError('--hidden switches on simulator effects: use it with --sim')
        names = setup.geometry.fans.names
        data = load_sweeps(args.data[0], names)
        for path in args.data[1:]:
            data = data + load_sweeps(path, names)
    if getattr(args, 'position_lag', 0.0):
        from ..workbench.sync import repaired
        data = repaired(data, args.position_lag)
    # faults in time, repaired in the order they arose: the zero on the recording clock first
    if getattr(args, 'zero_drift', 'none') != 'none':
        from ..workbench.time_repairs import zero_drift_repaired
        data = zero_drift_repaired(data, args.zero_drift, setup.geometry.fans.enabled)
    if getattr(args, 'skip_first', 0.0):
        from ..workbench.time_repairs import skip_first
        data = skip_first(data, args.skip_first)
    return data


def _model_path(setup, path):
    if path:
        return Path(path)
    ref = setup.config_dir / REFERENCE_FILE
    return ref if ref.is_file() else setup.model_path


def _out(args, command):
    return args.out or Path('reports') / time.strftime(f'model-{command}-%Y%m%d-%H%M%S')


def _library(args):
    from ..workbench.library import FAMILIES, Library
    extra = _load_plugins(args.plugin)
    families = list(FAMILIES) if not getattr(args, 'families', None) else args.families.split(',')
    return Library(families + extra)


# -- commands ---------------------------------------------------------------------------------------

def _cmd_fit(args) -> int:
    from ..workbench.commands import fit_command
    _load_plugins(args.plugin)
    setup = _setup(args)
    out = _out(args, 'fit')
    if args.commission:
        return _commission(setup, args, out)
    path = _model_path(setup, args.model)
    model = setup.load_model(path)
    data = _data(setup, args)
    res = fit_command(model, data, setup.geometry, out, save=args.save, source_model=str(path))
    if args.save:
        _keep_maps(setup, args.save, data)
    held = res.heldout
    print(f'fitted {path} on {data.source}: training RMSE {res.fit.rmse:.3f} N'
          + (f', held-out model error {held["model_rmse"]:.3f} N (noise {held["noise_sd"]:.3f} N)' if held else ''))
    if not held:
        n = len(data)
        print(f'nothing held out: {n} sweep{"" if n == 1 else "s"} (3 or more are needed to keep '
              f'some out), so the fit is not judged on sweeps it did not see, and on sweeps at so few '
              f'commands its parameters and their errors mean little; record more at varied commands '
              f'(`wind-shaper collect --design lhs:6+level --out NAME`) and fit on all of them')
    print(f'report: {out}/ (report.html, report.md, summary.json)')
    return 0


def _commission(setup, args, out) -> int:
    from ..model import save_model
    from ..workbench.reference import commission, commission_on
    from ..workbench.report import Report
    if args.sim == bool(args.data):
        raise WindShaperError('--commission fits the reference on --data RUN_OR_BAG (sweeps at varied '
                              'commands, e.g. from `wind-shaper collect --design lhs:12 --out NAME`) '
                              'or on the held-plate batch of the simulated tunnel (--sim)'
                              + (', not both' if args.sim else ''))
    if args.sim:
        ref = commission_on(_sim(setup, args))
        source = f'commissioning batch on the simulated tunnel (seed {args.seed})'
    else:
        data = _data(setup, args)
        ref = commission(data.fit_data(), setup.geometry.fans)
        source = f'{len(data)} moving-plate sweeps: {data.source}'
    save = args.save or (out / REFERENCE_FILE)
    save_model(save, ref.model, fitted_from=source,
               rmse_N=round(ref.fit.rmse, 5), n_samples=ref.fit.n,
               fitted_at=time.strftime('%Y-%m-%dT%H:%M:%S'))
    rep = Report('Commissioned reference model')
    rep.text(f'Fitted on {source}: {ref.fit.n} data points; RMSE {ref.fit.rmse:.4f} N.\n\n'
             f'Model: {ref.model!r}')
    rep.table(['fan', 'thrust gain', 'width scale', 'landing offset x [cm]', 'y [cm]'],
              [[k, f'{v["gain"]:.3f}', f'{v["width_scale"]:.3f}', f'{100 * v["offset_m"][0]:.1f}',
                f'{100 * v["offset_m"][1]:.1f}'] for k, v in ref.build().items()], heading='Each fan\'s build')
    rep.summary = {'command': 'fit --commission', 'fit': ref.fit.summary(), 'build': ref.build(),
                   'saved_model': str(save)}
    rep.write(out)
    print(f'commissioned reference (calibration RMSE {ref.fit.rmse:.4f} N) written to {save}')
    print(f'report: {out}/')
    return 0


def _cmd_compare(args) -> int:
    from ..workbench.commands import compare_command
    _load_plugins(args.plugin)
    setup = _setup(args)
    paths = [Path(p) for p in (args.model or [])] or [_model_path(setup, None)]
    models = {}
    for p in paths:
        label = p.stem if p.stem not in models else str(p)
        models[label] = setup.load_model(p)
    data = _data(setup, args)
    out = _out(args, 'compare')
    compare_command(models, data, setup.geometry, out, refit=not args.no_refit)
    doc = json.loads((out / 'summary.json').read_text())
    for label, m in doc['models'].items():
        print(f'{label:20s} held-out model error {m["heldout_model_rmse_N"]:.3f} N, '
              f'RMSE {m["heldout_raw"]["rmse"]:.3f} N')
    print(f'report: {out}/')
    return 0


def _cmd_diagnose(args) -> int:
    from ..workbench.commands import diagnose_command
    from ..workbench.diagnose import Diagnosis
    library = _library(args)
    setup = _setup(args)
    path = _model_path(setup, args.model)
    model = setup.load_model(path)
    data = _data(setup, args)
    out = _out(args, 'diagnose')
    bounds = setup.shaping.bounds
    d = diagnose_command(model, data, setup.geometry, out,
                         diagnosis=Diagnosis(library, max_effects=args.max_effects, noise_sd=args.noise_sd),
                         truth=_hidden(args) if args.sim else (),
                         suggest=args.suggest, goal=args.goal, bounds=(bounds.u_min, bounds.u_max))
    print(d.summary())
    if d.suggestion_ is not None:
        s = d.suggestion_
        print(f'suggested {len(s.design)} sweeps ({s.goal}: {s.outcome_text()}); saved as '
              f'{out / SUGGESTED_DESIGN}')
        print(f'next: wind-shaper collect --design {out / SUGGESTED_DESIGN} --out <name>, then '
              f'diagnose again with --data for both experiments')
    print(f'report: {out}/ (report.html, report.md, summary.json)')
    return 0


def _u0(text):
    """--u0: None (shaping.yaml), 'warm', or a command."""
    if text is None or text == 'warm':
        return text
    try:
        return float(text)
    except ValueError:
        raise WindShaperError(f"--u0 must be 'warm' or a command between 0 and 1, e.g. 0.5; got {text!r}") from None


def _cmd_add(args) -> int:
    from ..workbench.closed_loop import compare_closed_loop
    from ..workbench.commands import _added_text, add_command
    library = _library(args)
    setup = _setup(args)
    path = _model_path(setup, args.model)
    model = setup.load_model(path)
    additions = list(args.effect or [])
    if args.from_diagnosis:
        found = _diagnosis_findings(args.from_diagnosis)
        if not found and not additions:
            raise WindShaperError(f'nothing to add: the diagnosis in {args.from_diagnosis} found no effect and '
                                  f'offered no formula or discrepancy term to add; to add one anyway, name '
                                  f'it with --effect NAME (a candidate such as fan_gain[HM2] or swirl, a '
                                  f'term kind, or discrepancy to stand in for the unexplained rest)')
        additions += found
    if not additions:
        raise WindShaperError('nothing to add: give --effect NAME (a candidate such as fan_gain[HM2] or '
                              'swirl, or a term kind) or --from-diagnosis <summary.json>')
    data = _data(setup, args)
    out = _out(args, 'add')
    if args.closed_loop and not args.sim:
        raise WindShaperError('--closed-loop runs on the simulated tunnel: add --sim')
    effects = _hidden(args) if args.sim else []
    rule = {'method': args.rule} if args.rule else None

    def loop(models):
        return compare_closed_loop(setup, models, lambda s: setup.make_sim(seed=s, effects=effects),
                                   target=args.closed_loop, iterations=args.iterations,
                                   seeds=tuple(range(args.loop_seeds)), rule_overrides=rule,
                                   u0=_u0(args.u0))
    save = args.save or (out / 'model.yaml')
    res = add_command(model, additions, data, setup.geometry, out, save=save, library=library,
                      closed_loop=loop if args.closed_loop else None, noise_sd=args.noise_sd)
    _keep_maps(setup, save, data)
    print(f'added {", ".join(_added_text(a) for a in res.added)} (refitted on the training sweeps)')
    print(f'{res.change}; new model written to {save}')
    if res.closed_loop is not None:
        k = res.closed_loop.errors[next(iter(res.closed_loop.errors))].shape[1] - 1
        print('closed loop, true-field RMSE at iteration '
              f'{k}: ' + ', '.join(f'{lab} {v:.3f} N' for lab, v in res.closed_loop.at(k).items()))
    print(f'report: {out}/')
    return 0


def _keep_maps(setup, save, data):
    """The sweeps' field maps into the saved model file, as `calibrate --data` keeps them."""
    from ..workbench.calibrate import keep_commissioning_maps
    if save is not None and Path(save).is_file():
        keep_commissioning_maps(save, data, setup.shaping.make_estimator(setup.load_model(save)),
                                setup.geometry.key_points)


def _diagnosis_findings(path) -> list:
    """[(candidate, params)] of the findings in a `model diagnose` summary.json."""
    try:
        doc = json.loads(Path(path).read_text())
    except OSError as exc:
        raise WindShaperError(f'cannot read --from-diagnosis {path}: {exc.strerror or exc}; give the '
                              f'summary.json of a `wind-shaper model diagnose` report folder') from None
    except ValueError as exc:
        raise WindShaperError(f'--from-diagnosis {path} is not JSON ({exc}); give the summary.json of a '
                              f'`wind-shaper model diagnose` report folder') from None
    if not isinstance(doc, dict) or doc.get('command') != 'diagnose':
        raise WindShaperError(f'--from-diagnosis {path} is not the summary.json of `wind-shaper model '
                              f'diagnose`')
    found = [(f['candidate'], f['params']) for f in doc.get('findings', [])]
    if (doc.get('formula') or {}).get('offered'):
        found.append(('formula', {}))  # refitted on the data given, after the findings
    elif (doc.get('discrepancy') or {}).get('offered'):
        found.append(('discrepancy', {}))
    return found


# -- argument layer ---------------------------------------------------------------------------------

def _common(p, multi_model=False):
    p.add_argument('--config', type=Path, default=None, help='config folder (default: the shipped one)')
    p.add_argument('--disable', action='append', default=[], metavar='FAN', help='a disabled fan; repeat')
    src = p.add_argument_group('sweeps')
    src.add_argument('--sim', action='store_true', help='sweep the simulated tunnel (config sim.yaml)')
    src.add_argument('--hidden', action='append', default=[], metavar='EFFECT[:k=v,...]',
                     help='switch on a simulator hidden effect, e.g. weak_fan:fan=HM2,gain=0.8 or '
                          'tilted_fan:fan=LM2,shift=0.04/0; repeat for more (with --sim)')
    src.add_argument('--sweeps', type=int, default=12, help='simulated sweeps (first and last with fans off)')
    src.add_argument('--samples', type=int, default=1000, help='plate samples per simulated sweep')
    src.add_argument('--seed', type=int, default=0, help='simulator seed')
    src.add_argument('--data', type=Path, action='append', default=[],
                     help='recorded sweeps: an experiment folder or bag of `wind-shaper collect`, a '
                          'coordinator run folder, a rosbag2 bag or a shape report; repeat to pool '
                          'several (e.g. an experiment and its suggested follow-up)')
    src.add_argument('--position-lag', type=float, default=0.0, metavar='S',
                     help='pair each force with the plate\'s position S seconds later: for motion '
                          'capture that arrived S late (negative: early); the diagnosis measures it '
                          '("the positions arrive 40 ms late" is 0.040)')
    src.add_argument('--zero-drift', choices=('none', 'interpolate'), default='none',
                     help='repair a force-sensor zero that drifted: interpolate it linearly in '
                          'recording time between the fans-off sweeps and subtract its change '
                          '(the diagnosis says when the fans-off sweeps disagree)')
    src.add_argument('--skip-first', type=float, default=0.0, metavar='S',
                     help='leave out the first S seconds of each sweep: for sweeps that started '
                          'before the fans settled (the diagnosis names S)')
    if multi_model:
        p.add_argument('--model', type=Path, action='append', default=None,
                       help='a model file; repeat to compare several (default: the reference)')
    else:
        p.add_argument('--model', type=Path, default=None,
                       help=f'model file (default: {REFERENCE_FILE} in the config folder, else model.yaml)')
    p.add_argument('--plugin', action='append', default=[], metavar='FILE.py|MODULE',
                   help='import your own terms (and candidate FAMILIES) first; repeat for more')
    p.add_argument('--out', type=Path, default=None, help='report folder (default: reports/model-<cmd>-<time>)')
    p.add_argument('--noise-sd', type=float, default=None, metavar='N',
                   help='measurement noise per sample [N], when the held-out sweeps are too short to '
                        'estimate it (they must revisit places)')


def register(subparsers) -> None:
    model = subparsers.add_parser(
        'model', help='the model workbench: fit, compare, diagnose, add effects',
        description='Compare the model with sweeps, see where it fails, find the physical effect it '
                    'misses, add it and watch the error fall (docs/workbench.md).')
    sub = model.add_subparsers(dest='model_command', required=True, metavar='{fit,compare,diagnose,add}')

    p = sub.add_parser('fit', help='fit the model to sweeps with uncertainties; scores, held-out error, '
                                   'residual maps')
    _common(p)
    p.add_argument('--save', type=Path, default=None, help='write the fitted model file here')
    p.add_argument('--commission', action='store_true',
                   help='instead: fit the reference model (each fan\'s gain, width, landing; curve bend '
                        'and flatness per group) on --data sweeps, or on the commissioning batch of '
                        'the simulated tunnel (--sim); saved as reference.yaml, what diagnose measures '
                        'changes against')
    p.set_defaults(func=_cmd_fit)

    p = sub.add_parser('compare', help='several models against the same sweeps, side by side')
    _common(p, multi_model=True)
    p.add_argument('--no-refit', action='store_true', help='score the models as they are (no refit)')
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser('diagnose', help='find which physical effect the model misses')
    _common(p)
    p.add_argument('--families', default=None,
                   help='comma-separated candidate families (default: all; see docs/workbench.md)')
    p.add_argument('--max-effects', type=int, default=3, help='most effects forward selection adds')
    p.add_argument('--suggest', type=int, default=0, metavar='N',
                   help=f'also suggest the N next sweeps that teach the diagnosis most, saved as '
                        f'{SUGGESTED_DESIGN} in the report folder for `wind-shaper collect --design`')
    p.add_argument('--goal', choices=('auto', 'separate', 'shrink', 'explore'), default='auto',
                   help='what the suggested sweeps are for: separate the leading candidate effects, '
                        'shrink the fitted parameters\' uncertainty, explore commands not recorded '
                        'yet, or auto (explore when nothing was found, separate when the finding has '
                        'a close runner-up, else shrink)')
    p.set_defaults(func=_cmd_diagnose)

    p = sub.add_parser('add', help='add effects to the model, refit, before/after report, new model file')
    _common(p)
    p.add_argument('--effect', action='append', default=[], metavar='NAME[:k=v,...]',
                   help='a library candidate (fan_gain[HM2], swirl, wall_layer, ...), a registered '
                        'term kind (your own, with --plugin), discrepancy (a Gaussian process of '
                        'what the rest leaves, fitted last; no physics) or formula (a sparse formula '
                        'of it); repeat for more')
    p.add_argument('--from-diagnosis', type=Path, default=None, metavar='SUMMARY_JSON',
                   help='add the findings of `model diagnose` (its summary.json), and the formula or '
                        'discrepancy term it offered for the rest')
    p.add_argument('--save', type=Path, default=None, help='new model file (default: <out>/model.yaml)')
    p.add_argument('--closed-loop', default=None, metavar='TARGET',
                   help='also run the shaping loop on the simulated tunnel with the old and the new '
                        'model toward TARGET (uniform, parabolic, gaussian@FAN, ...)')
    p.add_argument('--iterations', type=int, default=6, help='closed-loop updates')
    p.add_argument('--loop-seeds', type=int, default=1, help='closed-loop runs per model (seeds 0..N-1)')
    p.add_argument('--rule', default=None, help='update rule for the closed loop (default: shaping.yaml)')
    p.add_argument('--u0', default=None, metavar='warm|COMMAND',
                   help="closed-loop start: 'warm' (each model's own optimum) or one command for "
                        'every fan (the paper: 0.5; with --rule paper that is the paper\'s protocol, '
                        'where the better model shows as the better search direction); default: '
                        'shaping.yaml u0')
    p.set_defaults(func=_cmd_add)
