"""``gimbal-friction loop-study``: the closed loop over temperature plateaus and profiles with each compensation case.

Thin: parse -> :mod:`gimbal_friction.runs.loop_study` (offline) / :mod:`gimbal_friction.runs.loop_live`
(``--live``) -> one
line on error. See those modules for what is computed and written.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from gimbal_friction.cli._common import add_common, parse_temperature_spec, print_json, progress, refuse_existing
from gimbal_friction.common.errors import ConfigError, GimbalFrictionError

CASE_CHOICES = ('none', 'constant', 'feedforward', 'refit', 'learned', 'chamber', 'bound', 'ideal',
                'feedforward_measured', 'feedforward_reference', 'dynamic', 'dynamic_unguarded')
DEFAULT_CASES = 'none,constant,feedforward,refit,learned,chamber,bound,ideal'


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        'loop-study', help='closed-loop study: the simulated axis over temperature plateaus and profiles with each '
        'compensation case; table, JSON, figures',
        description="Simulate the seeker's stabilization loop of one gimbal axis (truth friction, the simulator's "
        "own whatever the configuration under test says: the paper's bearing with a lubricant that differs from the "
        'datasheet, LuGre breakaway and pre-sliding, position ripple, the measured CW/CCW asymmetry) over '
        'temperature plateaus and profiles, with each compensation case: none, constant (temperature-blind Coulomb '
        "tuned at +20 degC), feedforward (the suite's, as configured), refit (the feedforward after a refit from "
        "the residual rows the suite's estimator collected over a service history on another seed), learned (the "
        "feedforward with one correction learned online over that service history with the node's settings, then "
        'frozen and scored on every profile; the learning run is reported as learning), dynamic (learned plus a '
        'pre-sliding term, a Dahl state in place of the smooth sign, learned and guarded from the same history; '
        'dynamic_unguarded: the term wherever it was fitted), chamber (the correction '
        "learned from a simulated chamber test of the same truth through the suite's chamber path), bound (the "
        "truth's own static map through the feedforward's delivery), ideal (the truth cancelled). "
        'Reports the LOS rate and position error RMS and peak, the peak error at reversals and the current margin.')
    add_common(parser)
    parser.add_argument('--axis', metavar='NAME', help='configured axis to simulate (default: the first)')
    parser.add_argument('--temperatures', default='-40,-20,0,20,40,60', metavar='SPEC',
                        help="temperature plateaus, '-40,0,60' or 'start:stop:step' [degC] (default -40:60:20)")
    parser.add_argument('--profiles', default='tracking,scan,pointing,weave', metavar='LIST',
                        help='profiles: tracking (1/3 rpm with reversals), scan (sine), pointing (fixed target under '
                        'base motion), weave (tracking under base motion: never in the learning history); '
                        'comma-separated (default all)')
    parser.add_argument('--cases', default=DEFAULT_CASES, metavar='LIST',
                        help=f'cases, comma-separated, from {", ".join(CASE_CHOICES)} (default {DEFAULT_CASES})')
    parser.add_argument('--truth', type=Path, metavar='PATH',
                        help="YAML file of the simulated truth's parameters (flat or in a gimbal_sim section; the "
                        'truth group of config/gimbal_sim.yaml plus temperature_bias_c, '
                        'temperature_sensor_time_constant_s, thermal_time_constant_s, inertia_truth_ratio, '
                        'disturbance_torque_nm, unbalance_torque_nm, unbalance_phase_rad), layered over the '
                        'configuration; default the packaged truth')
    parser.add_argument('--short', action='store_true', help='short profiles (one reversal each; for CI)')
    parser.add_argument('--latency-s', type=float, metavar='S',
                        help='transport latency of the feedforward [s] (default feedforward_latency_s, 0.001)')
    parser.add_argument('--estimator-method', choices=('observer', 'steady_state', 'both'), default='observer',
                        help="how the estimator collects case (d)'s data (default observer: while the gimbal works)")
    parser.add_argument('--refit-fit', default=None, metavar='LIST',
                        help='parameters refitted for case (d) (default walther_a,direction_asymmetry_cold,'
                        'direction_asymmetry_warm)')
    parser.add_argument('--learn-rate', type=float, default=None, metavar='NM_PER_MIN',
                        help='case learned: largest change of the applied correction per minute [N*m/min] (default '
                        "0.01, 33x the node's: the study compresses a service life into its history; the only setting "
                        "the study changes, stated in the JSON's settings.differs_from_node_default)")
    parser.add_argument('--learn-prior', type=float, default=None, metavar='N',
                        help="cases learned/chamber: prior samples n0 (default the node's, 50; another value is "
                        'reported in settings.differs_from_node_default)')
    parser.add_argument('--learn-position-bins', type=int, default=None, metavar='N', help=argparse.SUPPRESS)
    parser.add_argument('--learn-judge', choices=('on', 'off'), default='on',
                        help="case learned: the loop's error judges each cell of the correction in randomised on/off "
                        "blocks (on, default: the node's learning_judge with a loop-error input) or the residual "
                        'guard alone (off)')
    parser.add_argument('--learn-factor', type=float, default=None, metavar='X',
                        help='cases learned/refit: passes of the service history (64 s each, 19 s with --short), on '
                        'another noise seed (default 2)')
    parser.add_argument('--truths', type=int, default=None, metavar='N',
                        help='run the study over N truths of the seeded generator (lubricant, Walther slope, '
                        'Palmgren factor, asymmetry, ripple periods, Stribeck curve, unbalance, motor, sensor, '
                        'inertia, base motion: gimbals nobody described) and report the fraction of cells that meet '
                        'each learning goal; --out also writes each truth as a --truth file')
    parser.add_argument('--truth-seed', type=int, default=0, metavar='S',
                        help='first truth of the generator for --truths (default 0; truth k is the same everywhere)')
    parser.add_argument('--jobs', type=int, default=1, metavar='J',
                        help='with --truths: truths studied at once in worker processes (default 1)')
    parser.add_argument('--explain', action=argparse.BooleanOptionalAction, default=None,
                        help='name the truth term responsible for each missed learning goal (reruns the missed cells '
                        'with each term off, short durations; default on, off with --short)')
    parser.add_argument('--seed', type=int, metavar='N', help='sensor-noise seed (default the configured seed, 0)')
    parser.add_argument('--out', type=Path, metavar='DIR',
                        help="write loop_study.json, loop_study.txt, figures/ and residuals/ (case d's log) here")
    parser.add_argument('--live', action='store_true',
                        help='also run the real nodes (gimbal_sim, friction_feedforward, friction_estimator, '
                        'residual_logger) on loopback in real time and compare with the offline run')
    parser.add_argument('--live-temperature', type=float, default=-40.0, metavar='C',
                        help='plateau of the live runs [degC] (default -40)')
    parser.add_argument('--live-profile', default='tracking', metavar='NAME', help='profile of the live runs')
    parser.add_argument('--live-cases', default='feedforward', metavar='LIST',
                        help='cases of the live runs: feedforward, none and/or learning (friction_feedforward '
                        'learning in service with the --learn-* settings into live/correction.yaml, saved, stopped, '
                        'restarted on the file and run again; fails if it learned, saved or resumed nothing) '
                        '(default feedforward)')
    parser.add_argument('--live-duration-s', type=float, metavar='S',
                        help="duration of a live run [s] (default the profile's, or the short one with --short)")
    parser.add_argument('--live-realtime-factor', type=float, default=1.0, metavar='X',
                        help='simulated seconds per wall second of the live runs (default 1; below 1 on a busy '
                        'machine: the nodes see the same stamps, fewer messages per wall second)')
    parser.add_argument('--live-publish-every', type=int, default=2, metavar='N',
                        help='gimbal_sim publishes joint states / current / reference every N controller ticks '
                        '(default 2: 500 Hz; four Python processes at 1 kHz saturate a small machine and the '
                        'transport latency grows a long tail)')
    parser.set_defaults(func=run)


class StageProgress:
    """The study's progress on stderr: a bar on a terminal; otherwise (a log, a pipe) one short line as each stage
    starts and every ``every_s`` [s] within a long one, with the time since ``t0`` [s] (``clock``'s) and the share of
    the study done, so minutes of work are never silent."""

    def __init__(self, t0: float, stream: Any = None, every_s: float = 30.0,
                 clock: Any = time.perf_counter) -> None:
        self.t0, self.stream, self.every_s, self.clock = t0, stream, every_s, clock
        self._stage, self._last = '', -math.inf

    def __call__(self, stage: str, frac: float) -> None:
        out = self.stream if self.stream is not None else sys.stderr
        if out.isatty():
            progress(int(frac * 1000), 1000, f'loop-study {stage[:44]:<44}', stream=out)
            return
        now = self.clock()
        if stage != self._stage or now - self._last >= self.every_s:
            self._stage, self._last = stage, now
            print(f'loop-study: {stage} ({now - self.t0:.0f} s, {100 * frac:.0f} % done)', file=out, flush=True)


def _names(text: str, option: str, allowed: tuple[str, ...]) -> list[str]:
    names = [x.strip() for x in text.split(',') if x.strip()]
    if not names:
        raise ConfigError(option, 'needs at least one name', text)
    for n in names:
        if n not in allowed:
            raise ConfigError(option, f'unknown name (choose from {", ".join(allowed)})', n)
    return list(dict.fromkeys(names))


def _learn_setup(args: argparse.Namespace) -> Any:
    """The study's learning setup with the --learn-* options (validated by the study)."""
    from gimbal_friction.sim.study import LearnSetup
    base = LearnSetup()
    corr, lrn, factor = base.correction, base.learning, base.duration_factor
    if args.learn_prior is not None:
        corr = dataclasses.replace(corr, prior_samples=args.learn_prior)
    if args.learn_position_bins is not None:
        raise ConfigError('--learn-position-bins', 'is retired: ripple periods are now found in the data, no position '
                          'map is given (see docs/closed-loop.md)', args.learn_position_bins)
    if args.learn_rate is not None:
        lrn = dataclasses.replace(lrn, max_rate_nm_per_min=args.learn_rate)
    if args.learn_factor is not None:
        factor = args.learn_factor
    return LearnSetup(corr, lrn, factor, base.judge if getattr(args, 'learn_judge', 'on') == 'on' else None)


def _run_truths(args: argparse.Namespace, inputs: Any, temperatures: list[float], profiles: list[str],
                cases: list[str], learn: Any, show: Any, t0: float) -> int:
    """``--truths N``: the study over generated truths, its goal fractions."""
    from gimbal_friction.runs.truth_study import truths_study, truths_text, write_truth_files
    for flag, given in (('--truth', args.truth is not None), ('--live', args.live), ('--explain', bool(args.explain))):
        if given:
            raise ConfigError(flag, 'cannot be combined with --truths (study one generated truth with --truth and '
                              'the files --out writes)', True)
    if not 1 <= args.truths <= 10000:
        raise ConfigError('--truths', 'must be an integer in [1, 10000]', args.truths)
    if not 1 <= args.jobs <= 64:
        raise ConfigError('--jobs', 'must be an integer in [1, 64]', args.jobs)
    if args.out is not None:
        refuse_existing(args.out / 'truths.json', '--out', force=False)
    def show_truth(stage: str, frac: float) -> None:
        # a truth takes minutes: without a terminal for the bar, one line per truth done (a log shows progress)
        if sys.stderr.isatty():
            show(stage, frac)
        else:
            print(f'loop-study: {stage} done ({time.perf_counter() - t0:.0f} s)', file=sys.stderr, flush=True)

    doc = truths_study(inputs, args.truths, args.truth_seed, jobs=args.jobs, short=args.short,
                       temperatures=temperatures, profiles=profiles, cases=cases, learn=learn, progress=show_truth)
    doc['wall_s'] = round(time.perf_counter() - t0, 1)
    text = truths_text(doc)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / 'truths.json').write_text(json.dumps(doc, indent=1, default=float))
        (args.out / 'truths.txt').write_text(text)
        written = write_truth_files(args.out / 'truths', doc)
        print(f'loop-study: wrote {args.out / "truths.json"}, truths.txt and {len(written)} truth files',
              file=sys.stderr)
    if args.format == 'json':
        print_json(doc)
    else:
        sys.stdout.write(text)
    return 0


def run(args: argparse.Namespace) -> int:
    from gimbal_friction.refit.fit import FIT_PARAMETERS
    from gimbal_friction.runs.loop_study import (
        explain,
        load_study_inputs,
        study,
        study_document,
        table_text,
        write_outputs,
    )
    from gimbal_friction.sim.config import PROFILES
    from gimbal_friction.sim.study import DEFAULT_REFIT_FIT, goal_checks

    temperatures = [float(t) for t in parse_temperature_spec(args.temperatures)]
    profiles = _names(args.profiles, '--profiles', PROFILES)
    cases = _names(args.cases, '--cases', CASE_CHOICES)
    fit = _names(args.refit_fit, '--refit-fit', FIT_PARAMETERS) if args.refit_fit else list(DEFAULT_REFIT_FIT)
    if args.latency_s is not None and not (math.isfinite(args.latency_s) and 0.0 <= args.latency_s <= 1.0):
        raise ConfigError('--latency-s', 'must lie in [0, 1] [s]', args.latency_s)
    live_cases = _names(args.live_cases, '--live-cases', ('feedforward', 'none', 'learning')) if args.live else []
    if args.live and not (0.01 <= args.live_realtime_factor <= 100.0):
        raise ConfigError('--live-realtime-factor', 'must lie in [0.01, 100] [-]', args.live_realtime_factor)
    if args.live and not 1 <= args.live_publish_every <= 10000:
        raise ConfigError('--live-publish-every', 'must be an integer in [1, 10000]', args.live_publish_every)
    if args.live and args.live_profile not in PROFILES:
        raise ConfigError('--live-profile', f'must be one of {", ".join(PROFILES)}', args.live_profile)
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise ConfigError('--out', 'must be a folder', str(args.out))
    if args.out is not None:
        refuse_existing(args.out / 'residuals', '--out', what='a log')
        if 'learning' in live_cases:   # live learning starts from an empty correction
            from gimbal_friction.runs.live_learning import CORRECTION_FILE
            refuse_existing(args.out / 'live' / CORRECTION_FILE, '--out')
    inputs = load_study_inputs(args.config, args.axis, latency_s=args.latency_s, seed=args.seed,
                               truth_path=args.truth)

    t0 = time.perf_counter()
    show = StageProgress(t0)
    learn = _learn_setup(args)
    if args.truths is not None:
        return _run_truths(args, inputs, temperatures, profiles, cases, learn, show, t0)
    result = study(inputs, temperatures=temperatures, profiles=profiles, cases=cases, short=args.short,
                   estimator_method=args.estimator_method, refit_fit=fit, learn=learn, progress=show)
    goals = goal_checks(result.records)
    explained = None
    if args.explain if args.explain is not None else not args.short:
        show('explain missed goals', 1.0)
        explained = explain(result, inputs, goals, learn=learn)
    live = None
    if args.live:
        from gimbal_friction.runs.loop_live import live_study
        live = live_study(inputs, temperature_c=args.live_temperature, profile=args.live_profile,
                          cases=live_cases, short=args.short, duration_s=args.live_duration_s,
                          realtime_factor=args.live_realtime_factor, publish_every_ticks=args.live_publish_every,
                          work_dir=(args.out / 'live') if args.out is not None else None,
                          log=lambda text: print(text, file=sys.stderr, flush=True), learn=learn)
    doc = study_document(result, inputs, live=live, goals=goals, explained=explained, learn=learn)
    doc['wall_s']['total'] = round(time.perf_counter() - t0, 3)
    if args.out is not None:
        written = write_outputs(args.out, doc, result)
        print(f'loop-study: wrote {", ".join(str(p) for p in written[:2])}, {len(written) - 2} more in {args.out}',
              file=sys.stderr)
    if args.format == 'json':
        print_json(doc)
    else:
        sys.stdout.write(table_text(doc))
    failure = ((live or {}).get('learning') or {}).get('failure')
    if failure:   # the report is out; the command still fails: the live learning did not do its job
        msg = f'live learning: {failure}'
        raise GimbalFrictionError(msg)
    return 0
