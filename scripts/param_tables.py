"""Print the parameter tables of docs/ros.md from the code (the one source of names, defaults, units and meanings).

Run from the repository root: ``.venv/bin/python scripts/param_tables.py`` and paste the output into docs/ros.md
(``test/test_docs.py`` checks that every parameter is documented there with its default).
"""

from __future__ import annotations

import dataclasses
import math

from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
from gimbal_friction.estimation.estimator import EstimatorSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.params import parameter_specs


def fmt(value: object) -> str:
    if isinstance(value, float):
        if value != 0.0 and (abs(value) < 1e-3 or abs(value) >= 1e5):
            return f'{value:g}'
        return f'{value:.6g}'
    return str(value)


def settings_table(*classes: type) -> str:
    rows = ['| parameter | default | unit | meaning |', '|---|---|---|---|']
    for cls in classes:
        for f in dataclasses.fields(cls):
            meta = f.metadata
            desc = str(meta.get('description', '')).replace('|', '\\|')
            rows.append(f'| `{f.name}` | {fmt(f.default)} | {meta.get("unit", "")} | {desc} |')
    return '\n'.join(rows)


def model_table() -> str:
    rows = ['| parameter | default | unit | symbol | meaning |', '|---|---|---|---|---|']
    for s in parameter_specs():
        default = s['default']
        if isinstance(default, float) and math.isfinite(default):
            default = fmt(default)
        desc = str(s['description']).replace('|', '\\|')
        rows.append(f'| `{s["name"]}` | {default} | {s["unit"]} | {s["symbol"]} | {desc} |')
    return '\n'.join(rows)


if __name__ == '__main__':
    print('### Model parameters\n')
    print(model_table())
    print('\n**`friction_feedforward`**\n')
    print(settings_table(FeedforwardSettings, FeedforwardNodeSettings))
    print('\n**`friction_estimator`**\n')
    print(settings_table(EstimatorSettings, EstimatorNodeSettings))
    print('\n**`residual_logger`**\n')
    print(settings_table(LoggerSettings))
