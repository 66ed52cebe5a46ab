"""``gimbal-friction synth-bag``: write a synthetic chamber-test bag that follows the paper's protocol (Sec. 6).

The data come from :mod:`gimbal_friction.chamber.synth` (pure, seeded); the bag is written by
:func:`gimbal_friction.recording.bag_write.write_chamber_bag`. The bag directory holds only the bag: the truth behind
the data is printed in the summary (``--format json``: key ``truth``) and, with ``--truth-out FILE.yaml``, written
as a parameter file layerable with ``--config`` / ``--params-file``.

The bag is written into a temporary directory next to ``--out`` and renamed into place when complete, so a
failed or interrupted run leaves nothing at ``--out``. An existing non-empty ``--out`` is refused unless
``--force``, and even then only an existing rosbag2 bag directory (one with ``metadata.yaml``) is replaced.
The run is :func:`gimbal_friction.chamber.synth_bag.synth_bag`; this module maps the options and prints.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from gimbal_friction.chamber.synth import (
    DEFAULT_TRUTH_OVERRIDES,
    PRESETS,
    SynthConfig,
    preset_config,
)
from gimbal_friction.chamber.synth_bag import COMPRESSIONS, STORAGES, synth_bag
from gimbal_friction.cli._common import add_common, format_table, print_json, progress
from gimbal_friction.common.errors import ConfigError
from gimbal_friction.config.loader import all_axis_params, load_parameters

_DEFAULTS = SynthConfig()


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('synth-bag', help="write a synthetic chamber-test bag that follows the paper's test "
                            'protocol',
                            description='Write a rosbag2 chamber-test bag (/gimbal/temperature, /joint_states, '
                            '/gimbal/motor_current) following Yu & Shang (2017) Sec. 6: temperature plateaus held '
                            'in a chamber, ramps between them with the bearing lagging the chamber, the axis swept '
                            'at 1/3 rpm over -6..+11 deg, motor current from a truth model (a lubricant that '
                            'differs from the defaults) with position ripple, noise and a cold direction '
                            'asymmetry. Seeded: the same options give the same bag contents. Time is compressed: '
                            'the paper soaked each plateau 1 h.')
    parser.add_argument('--out', type=Path, required=True, metavar='DIR',
                        help='rosbag2 bag directory to create (refused if it exists and is not empty)')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing bag directory at DIR (and an existing --truth-out file)')
    parser.add_argument('--seed', type=int, default=_DEFAULTS.seed, metavar='N', help='random seed (default 0)')
    parser.add_argument('--plateaus', default=','.join(f'{t:g}' for t in _DEFAULTS.plateaus_c), metavar='LIST',
                        help='chamber plateaus in degC, in order; write --plateaus=-40,-20,... '
                        '(default -40,-20,0,20,40,60)')
    parser.add_argument('--hold-s', type=float, default=_DEFAULTS.hold_s, metavar='X',
                        help=f'measuring hold at each plateau after the soak [s] (default {_DEFAULTS.hold_s:g})')
    parser.add_argument('--soak-s', type=float, default=None, metavar='X',
                        help='soak at each plateau before the hold [s] (paper: 1 h; default: until the bearing '
                        f'is within {_DEFAULTS.settle_tol_c:g} degC of the plateau)')
    parser.add_argument('--ramp-rate', type=float, default=_DEFAULTS.ramp_rate_c_per_min, metavar='X',
                        help='chamber ramp rate between plateaus [degC/min] (chamber: 3-15; default '
                        f'{_DEFAULTS.ramp_rate_c_per_min:g})')
    parser.add_argument('--bearing-lag-s', type=float, default=_DEFAULTS.bearing_lag_s, metavar='X',
                        help='time constant of the bearing temperature lagging the chamber [s] (default '
                        f'{_DEFAULTS.bearing_lag_s:g})')
    parser.add_argument('--duration-s', type=float, default=None, metavar='X',
                        help='cut the test after X seconds (default: the whole schedule)')
    parser.add_argument('--joint-rate-hz', type=float, default=_DEFAULTS.joint_rate_hz, metavar='X',
                        help=f'/joint_states rate [Hz] (default {_DEFAULTS.joint_rate_hz:g})')
    parser.add_argument('--current-rate-hz', type=float, default=None, metavar='X',
                        help='/gimbal/motor_current rate [Hz] (default: the joint rate)')
    parser.add_argument('--temperature-rate-hz', type=float, default=_DEFAULTS.temperature_rate_hz, metavar='X',
                        help=f'/gimbal/temperature rate [Hz] (default {_DEFAULTS.temperature_rate_hz:g})')
    parser.add_argument('--current-noise-a', type=float, default=_DEFAULTS.current_noise_a, metavar='X',
                        help=f'motor current noise, standard deviation [A] (default {_DEFAULTS.current_noise_a:g})')
    parser.add_argument('--storage', choices=STORAGES, default='mcap', help='rosbag2 storage (default mcap)')
    parser.add_argument('--compression', choices=COMPRESSIONS, default=None,
                        help='zstd = MCAP chunk compression (what ros2 bag record --storage-preset-profile '
                        'zstd_fast writes; every MCAP/rosbags reader opens it), about 3x smaller; default: zstd for '
                        'mcap, none for sqlite3')
    parser.add_argument('--truth', type=Path, metavar='FILE.yaml',
                        help='parameter file whose model/axis values are the truth (layered over the packaged '
                        'defaults and --config); default: the configuration with '
                        + ', '.join(f'{k} = {v:.6g}' for k, v in DEFAULT_TRUTH_OVERRIDES.items()))
    parser.add_argument('--preset', choices=list(PRESETS), default='default',
                        help="paper = a test whose plateau means are the paper's four measured values (CW 3.19 / CCW "
                        '-2.45 N*mm at -40 degC, 1.05 / -1.34 at +60): truth lubricant, Palmgren factor and the '
                        'temperature-dependent direction asymmetry of physics/direction.py (default: the default truth '
                        'and a synthetic cold CCW asymmetry)')
    parser.add_argument('--truth-out', type=Path, metavar='FILE.yaml',
                        help='also write the truth as a parameter file (layerable with --config)')
    add_common(parser)
    parser.set_defaults(func=run)


# ---------------------------------------------------------------------------------------------- arguments
def parse_plateaus(spec: str) -> tuple[float, ...]:
    """``'-40,-20,0'`` to a tuple of temperatures [°C].

    >>> parse_plateaus('-40, -20,0')
    (-40.0, -20.0, 0.0)
    """
    try:
        values = tuple(float(x) for x in spec.split(',') if x.strip())
    except ValueError:
        raise ConfigError('--plateaus', "expected a comma-separated list in degC, e.g. '-40,-20,0,20,40,60'",
                          spec) from None
    if not values or not all(math.isfinite(v) for v in values):
        raise ConfigError('--plateaus', 'needs at least one finite temperature', spec)
    return values


def build_config(args: argparse.Namespace) -> SynthConfig:
    """The :class:`SynthConfig` of the command-line options (joints and truth from the parameter files)."""
    layers = list(args.config) + ([args.truth] if args.truth is not None else [])
    params = load_parameters(layers)
    truth = all_axis_params(params)
    preset = getattr(args, 'preset', 'default')
    overrides = dict(PRESETS[preset].get('truth_overrides', DEFAULT_TRUTH_OVERRIDES))
    return preset_config(preset,
        plateaus_c=parse_plateaus(args.plateaus), hold_s=args.hold_s, soak_s=args.soak_s,
        ramp_rate_c_per_min=args.ramp_rate, bearing_lag_s=args.bearing_lag_s, duration_s=args.duration_s,
        joint_rate_hz=args.joint_rate_hz, current_rate_hz=args.current_rate_hz,
        temperature_rate_hz=args.temperature_rate_hz, current_noise_a=args.current_noise_a, seed=args.seed,
        joints=tuple(truth), truth_base=truth,
        truth_overrides={} if args.truth is not None else overrides)


# ---------------------------------------------------------------------------------------------- run
def run(args: argparse.Namespace) -> int:
    cfg = build_config(args)
    data, doc = synth_bag(cfg, args.out, storage=args.storage, compression=args.compression, force=args.force,
                          truth_out=args.truth_out, progress=progress)
    compression, size = doc['compression'], doc['size_bytes']
    t2_t0 = doc['generate_s'] + doc['write_s']
    counts = doc['messages']
    if args.format == 'json':
        print_json(doc)
        return 0
    print(f'wrote {args.out} ({args.storage}, compression {compression}, {size / 1e6:.2f} MB) in {t2_t0:.1f} s: '
          f'{data.duration_s:.1f} s of chamber test ({data.duration_s / 60.0:.1f} min), seed {cfg.seed}')
    print(format_table([[t, str(n)] for t, n in counts.items()], ['topic', 'messages']))
    print()
    rows = [[f'{p.temperature_c:g}', f'{p.reached_s:.1f}', f'{p.hold_start_s:.1f}', f'{p.hold_end_s:.1f}']
            for p in data.plateaus]
    print(format_table(rows, ['plateau [degC]', 'reached [s]', 'hold from [s]', 'hold to [s]']))
    for joint, truth in doc['truth'].items():
        print()
        diffs = ', '.join(f'{k} = {v:.6g}' if isinstance(v, float) else f'{k} = {v}'
                          for k, v in truth['differs_from_defaults'].items()) or 'none'
        print(f'truth of {joint}: differs from the defaults in {diffs}; K_T = {truth["torque_constant_nm_per_a"]:g} '
              f'N*m/A, I_0 = {truth["no_load_current_a"]:g} A' + (f'; synthetic CCW/CW x {cfg.asym_ratio_cold:.3f} at '
              f'{cfg.asym_t_cold_c:g} degC -> 1 at {cfg.asym_t_ref_c:g} degC' if cfg.asym_ratio_cold != 1.0 else ''))
        rows = [[f'{r["temperature_c"]:g}', f'{r["viscosity_cst"]:.4g}', f'{r["truth_cw_nmm"]:.3f}',
                 f'{r["truth_ccw_nmm"]:.3f}', f'{r["default_model_nmm"]:.3f}'] for r in truth['plateaus']]
        print(format_table(rows, ['t [degC]', 'nu [cSt]', 'truth CW [N*mm]', 'truth CCW [N*mm]',
                                  'defaults [N*mm]']))
    if args.truth_out is not None:
        print(f'truth parameters: {args.truth_out}')
    sys.stdout.flush()
    return 0
