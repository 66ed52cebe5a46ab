"""Print the parameter tables of docs/ros.md from the code (the one source of names, defaults, units and meanings).

Run from the repository root: ``.venv/bin/python scripts/param_tables.py`` and paste the output into docs/ros.md
(``test/test_docs.py`` checks that every parameter is documented there with its default).
``--fix-docs`` rewrites the type and allowed columns of the tables in docs/ros.md from
``gimbal_friction.config.parameter_rules`` (``test/ros/test_parameter_descriptors.py`` compares them with what the
running nodes describe).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
from gimbal_friction.estimation.estimator import EstimatorSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.params import parameter_specs

DOCS = Path(__file__).resolve().parents[1] / 'docs' / 'ros.md'


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


# ------------------------------------------------------------------------------------- the type and allowed columns
#: the parameter tables of docs/ros.md: heading -> (the executable whose parameters it lists, name prefix)
DOC_TABLES = {'## chamber_replay': ('chamber_replay', ''), '## gimbal_sim': ('gimbal_sim', ''),
              '### Model parameters': ('friction_feedforward', 'model.'),
              '### friction_feedforward parameters': ('friction_feedforward', ''),
              '### friction_estimator parameters': ('friction_estimator', ''),
              '### residual_logger parameters': ('residual_logger', '')}
TYPE_WORDS = {bool: 'bool', int: 'int', float: 'double', str: 'string'}


def type_word(default: object) -> str:
    """The ROS type of a parameter with this default, as the tables write it (double, int[], string[], ...)."""
    if isinstance(default, (list, tuple)):
        items = list(default)
        if items and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
            return 'double[]' if any(isinstance(v, float) for v in items) else 'int[]'
        return 'string[]' if all(isinstance(v, str) for v in items) else 'bool[]'
    return TYPE_WORDS[type(default)]


def split_row(line: str) -> list[str]:
    """The cells of a Markdown table row (``\\|`` stays inside its cell)."""
    import re
    return [cell.strip() for cell in re.split(r'(?<!\\)\|', line.strip())[1:-1]]


def fix_docs(text: str) -> str:
    """docs/ros.md with the type and allowed columns of its parameter tables written from the code (a row's meaning
    and the rows of parameters without a rule are left as they are; chamber_replay's and gimbal_sim's tables get an
    allowed column)."""
    from gimbal_friction.config.parameter_rules import field_default, parameter_rule

    out, table = [], None
    for line in text.splitlines():
        if line.startswith('#'):
            table = DOC_TABLES.get(line.strip())
        elif table is not None and line.startswith('|'):
            cells = split_row(line)
            if cells[0] == 'parameter' and 'allowed' not in cells:
                cells.insert(cells.index('unit') + 1, 'allowed')
            elif set(line) <= set('|-') and len(cells) < len(out[-1].split('|')) - 2:
                cells.append('---')
            elif cells[0].startswith('`'):
                node, prefix = table
                name = prefix + cells[0].strip('`')
                header = split_row(next(h for h in reversed(out) if h.startswith('| parameter')))
                if len(cells) < len(header):
                    cells.insert(header.index('allowed'), '-')
                default = field_default(node, name)
                if default is not None:
                    cells[header.index('type')] = type_word(default)
                    rule = parameter_rule(node, name)
                    if rule is not None:
                        cells[header.index('allowed')] = rule.text(cells[header.index('unit')])
            line = '| ' + ' | '.join(cells) + ' |'
            line = line.replace('| --- |', '|---|').replace('| --- ', '|---')
            if set(line.replace(' ', '')) <= set('|-'):
                line = '|' + '|'.join('---' for _ in cells) + '|'
        out.append(line)
    return '\n'.join(out) + ('\n' if text.endswith('\n') else '')


if __name__ == '__main__' and sys.argv[1:] == ['--fix-docs']:
    DOCS.write_text(fix_docs(DOCS.read_text(encoding='utf-8')), encoding='utf-8')
elif __name__ == '__main__':
    print('### Model parameters\n')
    print(model_table())
    print('\n**`friction_feedforward`**\n')
    print(settings_table(FeedforwardSettings, FeedforwardNodeSettings))
    print('\n**`friction_estimator`**\n')
    print(settings_table(EstimatorSettings, EstimatorNodeSettings))
    print('\n**`residual_logger`**\n')
    print(settings_table(LoggerSettings))
