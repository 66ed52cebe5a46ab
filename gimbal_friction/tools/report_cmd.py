"""``gimbal-friction report``: the paper's figures from the model (Figs. 5, 7–11) as PNG files."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from gimbal_friction.core.model import friction_torque
from gimbal_friction.tools._common import add_common, format_table, load_axis, print_json


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('report', help='figures and tables: model components vs temperature (Fig. 11), '
                            'model vs measured by direction (Fig. 13)',
                            description='Draw the paper figures from the model into --out: free contact angle '
                            '(Fig. 5), axial force (Figs. 7-8), M_S+M_R (Figs. 9-10) and the components M_L, '
                            'M_S+M_R, M (Fig. 11).')
    add_common(parser)
    parser.add_argument('--axis', metavar='NAME', help='configured axis (default: the first in axes)')
    parser.add_argument('--out', type=Path, default=Path('report'), metavar='DIR',
                        help='output folder for the PNG files (default: ./report)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gimbal_friction.plots import model_figures
    axis, params, _ = load_axis(args)
    files = model_figures(params, args.out)
    temps = [-40.0, -20.0, 0.0, 20.0, 40.0, 60.0]
    res = friction_torque(params, temps)
    rows = res.records()
    if args.format == 'json':
        print_json({'axis': axis, 'figures': [str(f) for f in files], 'fig11': rows})
        return 0
    print(f'axis {axis}: figures written to {args.out}/')
    for f in files:
        print(f'  {f}')
    print()
    print(format_table([[f'{r["temperature_c"]:.0f}', f'{r["m_viscous_nmm"]:.3f}',
                         f'{r["m_sliding_nmm"] + r["m_rolling_nmm"]:.3f}', f'{r["m_total_nmm"]:.3f}']
                        for r in rows], ['t [degC]', 'M_L [N*mm]', 'M_S+M_R [N*mm]', 'M [N*mm]']))
    return 0
