"""``gimbal-friction model``: evaluate the model over temperatures (table, JSON, CSV, plot)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from gimbal_friction.cli._common import (
    add_common_noformat,
    csv_text,
    format_table,
    load_axis,
    parse_temperature_spec,
    print_json,
    refuse_existing,
)
from gimbal_friction.physics.model import CONTRACT_FIELDS, friction_torque
from gimbal_friction.physics.thermal import loose_fit_temperature
from gimbal_friction.physics.validity import (
    LUBRICANT_DATA_C,
    VALID_T_MAX_C,
    VALID_T_MIN_C,
    check_temperatures,
    validity_range,
)

DEFAULT_TEMPERATURES = '-40:60:10'

_TABLE_COLUMNS = (
    ('temperature_c', 't [degC]', '{:.1f}'),
    ('viscosity_cst', 'nu [cSt]', '{:.4g}'),
    ('free_contact_angle_deg', 'alpha0 [deg]', '{:.2f}'),
    ('contact_angle_deg', 'alpha [deg]', '{:.2f}'),
    ('radial_clearance_mm', 'P_d [um]', None),
    ('axial_force_n', 'F_a [N]', '{:.2f}'),
    ('ball_load_n', 'Q [N]', '{:.2f}'),
    ('m_rolling_nmm', 'M_R [N*mm]', '{:.3f}'),
    ('m_sliding_nmm', 'M_S [N*mm]', '{:.3f}'),
    ('m_viscous_nmm', 'M_L [N*mm]', '{:.3f}'),
    ('m_total_nmm', 'M [N*mm]', '{:.3f}'),
)


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('model', help='evaluate the model over temperatures: table, JSON, CSV or plot',
                            description='Friction torque of one gimbal axis (both bearings) and its components '
                            'versus temperature. Torques in N*mm as in the paper. Temperatures must lie in the '
                            f"model's validity range, {VALID_T_MIN_C:g}..{VALID_T_MAX_C:g} degC with the paper's "
                            'parameters (where the paper computed and measured the friction; its lubricant data '
                            f'reach {LUBRICANT_DATA_C[0]:g}..{LUBRICANT_DATA_C[1]:g} degC); narrower where the '
                            'bearing pair loses its preload (docs/model.md, "Validity range").')
    add_common_noformat(parser)
    parser.add_argument('--format', choices=['table', 'json', 'csv'], default='table', help='output format')
    parser.add_argument('--axis', metavar='NAME', help='configured axis (default: the first in axes)')
    parser.add_argument('--temperature', '-t', default=DEFAULT_TEMPERATURES, metavar='SPEC',
                        help="temperatures in degC: '-40,0,60' or 'start:stop:step' (stop inclusive), within "
                        f'{VALID_T_MIN_C:g}..{VALID_T_MAX_C:g} degC (others are refused); default '
                        f'{DEFAULT_TEMPERATURES}')
    parser.add_argument('--speed-rpm', type=float, metavar='X', help='shaft speed [rpm] (default: model.speed_rpm)')
    parser.add_argument('--interference-mm', type=float, metavar='X', help='override interference Delta [mm]')
    parser.add_argument('--gasket-mm', type=float, metavar='X', help='override gasket thickness P [mm]')
    parser.add_argument('--plot', type=Path, metavar='PNG', help='also draw M_L, M_S+M_R and M (paper Fig. 11; an '
                        'existing file is refused unless --force)')
    parser.add_argument('--force', action='store_true', help='replace an existing --plot file')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    axis, params, _ = load_axis(args)
    if args.plot is not None:
        refuse_existing(args.plot, '--plot', force=args.force)  # the one rule of every command's outputs
    changes: dict[str, float] = {}
    if args.interference_mm is not None:
        changes['interference_mm'] = args.interference_mm
    if args.gasket_mm is not None:
        changes['gasket_thickness_mm'] = args.gasket_mm
    if args.speed_rpm is not None:
        changes['speed_rpm'] = args.speed_rpm
    if changes:
        params = params.replace(**changes)
    temps = parse_temperature_spec(args.temperature)
    check_temperatures(params, temps, what='--temperature')   # one line for a temperature outside the range
    result = friction_torque(params, temps)
    records = result.records()
    if args.plot is not None:
        from gimbal_friction.plots.figures import plot_components
        plot_components(result, args.plot, title=f'{axis}: friction torque and components (paper Fig. 11), '
                        f'Delta = {params.interference_mm:g} mm, P = {params.gasket_thickness_mm:g} mm, '
                        f'n = {params.speed_rpm:.4g} rpm')
    if args.format == 'json':
        print_json(records)
    elif args.format == 'csv':
        sys.stdout.write(csv_text(records, list(CONTRACT_FIELDS)))
    else:
        rows = []
        for rec in records:
            row = []
            for key, _, fmt in _TABLE_COLUMNS:
                value = rec[key]
                row.append(f'{value * 1000:.2f}' if fmt is None else fmt.format(value))
            rows.append(row)
        loose = loose_fit_temperature(params)
        print(f'axis {axis}: friction torque of the whole axis ({params.bearings_per_axis} bearings), '
              f'n = {params.speed_rpm:.4g} rpm, Delta = {params.interference_mm:g} mm, '
              f'P = {params.gasket_thickness_mm:g} mm')
        print(f'outer ring loose in housing above {loose:.1f} degC' if math.isfinite(loose) else
              'outer ring fit does not change with temperature')
        valid = validity_range(params)
        print(f"the model's validity range: {valid.text}" + (f'; {valid.note}' if valid.note else ''))
        print(format_table(rows, [h for _, h, _ in _TABLE_COLUMNS]))
        if args.plot is not None:
            print(f'plot: {args.plot}')
    if args.plot is not None and args.format != 'table':
        print(f'plot: {args.plot}', file=sys.stderr)
    return 0
