"""Parameters as ``ros2 param describe`` shows them: the DescribeParameters answer of each running node against the
parameter tables of docs/ros.md (type, range, allowed values), and SetParameters with a value of the wrong type
refused through the real service with a one-line reason, the value keeping its type.

The nodes run as their own processes (``spawn``); the probe calls their ``/<node>/list_parameters``,
``/<node>/describe_parameters``, ``/<node>/get_parameters`` and ``/<node>/set_parameters`` services.
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path
from typing import Any

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / 'scripts'))
from param_tables import DOC_TABLES, split_row  # noqa: E402  (the docs' own table reader)

#: ParameterType -> the word the tables of docs/ros.md use
TYPE_WORDS = {ParameterType.PARAMETER_BOOL: 'bool', ParameterType.PARAMETER_INTEGER: 'int',
              ParameterType.PARAMETER_DOUBLE: 'double', ParameterType.PARAMETER_STRING: 'string',
              ParameterType.PARAMETER_INTEGER_ARRAY: 'int[]', ParameterType.PARAMETER_DOUBLE_ARRAY: 'double[]',
              ParameterType.PARAMETER_STRING_ARRAY: 'string[]', ParameterType.PARAMETER_BOOL_ARRAY: 'bool[]'}
_INTERVAL = re.compile(r'([\[(])(\S+), (\S+)([\])])')
_HALF = re.compile(r'(>=|>|<=|<) (\S+)')


def doc_rows() -> dict[str, dict[str, dict[str, str]]]:
    """executable -> parameter -> {column: cell} of the parameter tables of docs/ros.md (model rows as
    ``model.<name>``)."""
    out: dict[str, dict[str, dict[str, str]]] = {}
    table, header = None, None
    for line in (ROOT / 'docs' / 'ros.md').read_text(encoding='utf-8').splitlines():
        if line.startswith('#'):
            table, header = DOC_TABLES.get(line.strip()), None
        elif table is not None and line.startswith('| parameter'):
            header = split_row(line)
        elif table is not None and header and line.startswith('| `'):
            cells = dict(zip(header, split_row(line), strict=True))
            node, prefix = table
            out.setdefault(node, {})[prefix + cells['parameter'].strip('`')] = cells
    return out


def describe_all(probe: Any, node: str) -> dict[str, Any]:
    names = probe.call(ListParameters, f'/{node}/list_parameters', ListParameters.Request()).result.names
    answer = probe.call(DescribeParameters, f'/{node}/describe_parameters',
                  DescribeParameters.Request(names=list(names)))
    return {d.name: d for d in answer.descriptors}


def range_problems(name: str, allowed: str, desc: Any) -> list[str]:
    """What differs between the documented rule ``allowed`` and the descriptor's range and constraints."""
    rule, _, note = allowed.partition('; ')
    ranges = list(desc.floating_point_range) + list(desc.integer_range)
    big = sys.float_info.max if desc.floating_point_range else 2**63 - 1
    out = []
    if note and note not in desc.additional_constraints:
        out.append(f'{name}: the rule {note!r} is not in additional_constraints {desc.additional_constraints!r}')
    if rule.startswith('one of '):
        if ranges or not all(c in desc.additional_constraints for c in rule[7:].split(', ')):
            out.append(f'{name}: allowed values {rule!r}, descriptor {desc.additional_constraints!r}')
        return out
    m, h = _INTERVAL.match(rule), _HALF.match(rule)
    if m is None and h is None:
        return out   # a rule in words only (a path, a layout), no range
    if m is not None:
        low, high = float(m.group(2)), float(m.group(3))
    else:
        bound = float(h.group(2))
        low, high = (bound, big) if h.group(1).startswith('>') else (-big, bound)
    if len(ranges) != 1:
        return [*out, f'{name}: documented {rule!r}, descriptor has no range']
    got = (float(ranges[0].from_value), float(ranges[0].to_value))
    if not (math.isclose(got[0], low, rel_tol=1e-5, abs_tol=1e-12)
            and math.isclose(got[1], high, rel_tol=1e-5, abs_tol=1e-12)):
        out.append(f'{name}: documented {rule!r}, descriptor range [{got[0]!r}, {got[1]!r}]')
    if not desc.additional_constraints.startswith(rule.split(' ')[0]):
        out.append(f'{name}: additional_constraints {desc.additional_constraints!r} do not state {rule!r}')
    return out


@pytest.mark.slow
def test_describe_parameters_answers_what_the_documentation_tables_say(spawn, probe, tmp_path):
    """Every parameter of friction_feedforward, friction_estimator, residual_logger, gimbal_sim and chamber_replay
    documented in a table of docs/ros.md: DescribeParameters gives its documented type, fixed (not dynamic), and
    the documented range (a side without a bound: the largest finite value) and allowed values; every parameter a
    node declares from a settings table is documented (gimbal_sim's simulator parameters are in
    config/gimbal_sim.yaml)."""
    procs = {'friction_feedforward': spawn('friction_feedforward'),
             'friction_estimator': spawn('friction_estimator'),
             'residual_logger': spawn('residual_logger', '--ros-args', '-p', f'output_dir:={tmp_path / "log"}'),
             'gimbal_sim': spawn('gimbal_sim', '--ros-args', '-p', 'wait_for_subscribers:=100', '-p',
                                 'start_timeout_s:=3600.0'),
             # waits for subscribers (its services answer meanwhile); rate:=2 is an integer for a double
             'chamber_replay': spawn('chamber_replay', '--ros-args', '-p', f'bag:={ROOT / "bags" / "chamber_sample"}',
                                     '-p', 'rate:=2', '-p', 'wait_for_subscribers:=100', '-p',
                                     'wait_timeout_s:=3600.0')}
    docs = doc_rows()
    problems: list[str] = []
    checked = 0
    for node, proc in procs.items():
        described = describe_all(probe, node)
        assert proc.alive(), proc.output()
        rows = dict(docs.get(node, {}))
        if node in ('friction_estimator', 'gimbal_sim'):   # the model table (listed once, under the feedforward)
            rows = {**{n: r for n, r in docs['friction_feedforward'].items() if n.startswith('model.')}, **rows}
        for name, cells in rows.items():
            desc = described.get(name)
            if desc is None:
                problems.append(f'{node}: {name} documented, not declared')
                continue
            checked += 1
            if desc.dynamic_typing:
                problems.append(f'{node}: {name} is dynamically typed')
            if TYPE_WORDS.get(desc.type) != cells['type']:
                problems.append(f'{node}: {name} documented {cells["type"]}, declared {TYPE_WORDS.get(desc.type)}')
            if cells.get('allowed', '-') != '-':
                problems += [f'{node}: {p}' for p in range_problems(name, cells['allowed'], desc)]
        if node != 'gimbal_sim':
            # (qos_overrides.<topic>.<entity>.<policy>: declared by rclpy per publisher and subscription, documented
            # as one family in the QoS section of docs/ros.md)
            skip = ('use_sim_time', 'start_type_description_service', 'axes', 'axis.', 'qos_overrides.')
            undocumented = [n for n, d in described.items() if n not in rows and not n.startswith(skip)
                            and 'retired' not in d.description]
            problems += [f'{node}: {n} declared, not documented' for n in undocumented]
    assert problems == [], '\n'.join(problems)
    assert checked > 200
    assert get_one(probe, 'chamber_replay', 'rate') == value(ParameterType.PARAMETER_DOUBLE, 2.0)


def value(kind: int, v: Any) -> ParameterValue:
    field = {ParameterType.PARAMETER_INTEGER: 'integer_value', ParameterType.PARAMETER_DOUBLE: 'double_value',
             ParameterType.PARAMETER_STRING: 'string_value'}[kind]
    return ParameterValue(type=kind, **{field: v})


def set_one(probe: Any, node: str, name: str, pv: ParameterValue) -> Any:
    answer = probe.call(SetParameters, f'/{node}/set_parameters',
                  SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)]))
    return answer.results[0]


def get_one(probe: Any, node: str, name: str) -> ParameterValue:
    return probe.call(GetParameters, f'/{node}/get_parameters', GetParameters.Request(names=[name])).values[0]


@pytest.mark.slow
def test_a_value_of_the_wrong_type_is_refused_and_the_parameter_keeps_its_type(spawn, probe):
    """``-p max_torque_nm:=1`` (an integer on the command line) starts the node with the double 1.0; SetParameters
    with INTEGER 2 is then refused with one line naming the parameter and the type, and the value stays the
    double 1.0 (before, it was accepted and the parameter became an integer). A double for the integer
    ``model.ball_count`` and a string for the unset override ``axis.elevation.width_mm`` are refused alike; a
    double for that override is accepted and keeps its type."""
    node = 'friction_feedforward'
    proc = spawn(node, '--ros-args', '-p', 'max_torque_nm:=1', '-p', 'model.ball_count:=15')
    assert get_one(probe, node, 'max_torque_nm') == value(ParameterType.PARAMETER_DOUBLE, 1.0), proc.output()

    refused = set_one(probe, node, 'max_torque_nm', value(ParameterType.PARAMETER_INTEGER, 2))
    assert not refused.successful
    assert "'max_torque_nm'" in refused.reason and 'double' in refused.reason and '\n' not in refused.reason
    assert get_one(probe, node, 'max_torque_nm') == value(ParameterType.PARAMETER_DOUBLE, 1.0)

    refused = set_one(probe, node, 'model.ball_count', value(ParameterType.PARAMETER_DOUBLE, 16.0))
    assert not refused.successful and "'model.ball_count'" in refused.reason and 'integer' in refused.reason
    assert get_one(probe, node, 'model.ball_count') == value(ParameterType.PARAMETER_INTEGER, 15)

    override = 'axis.elevation.width_mm'
    refused = set_one(probe, node, override, value(ParameterType.PARAMETER_STRING, 'wide'))
    assert not refused.successful and f"'{override}' = 'wide': must be a number" in refused.reason
    refused = set_one(probe, node, override, value(ParameterType.PARAMETER_INTEGER, 5))
    assert not refused.successful and f"'{override}'" in refused.reason and 'double' in refused.reason
    assert get_one(probe, node, override).type == ParameterType.PARAMETER_NOT_SET
    assert set_one(probe, node, override, value(ParameterType.PARAMETER_DOUBLE, 5.0)).successful
    refused = set_one(probe, node, override, value(ParameterType.PARAMETER_INTEGER, 4))
    assert not refused.successful
    assert get_one(probe, node, override) == value(ParameterType.PARAMETER_DOUBLE, 5.0)

    # a value of the right type outside the range is refused with the validation's own reason, not rclpy's
    refused = set_one(probe, node, 'max_torque_nm', value(ParameterType.PARAMETER_DOUBLE, 0.0))
    assert not refused.successful and refused.reason == "parameter 'max_torque_nm' = 0.0: must lie in (0, 100] [N*m]"
    assert proc.alive(), proc.output()
