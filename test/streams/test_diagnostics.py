"""The nodes' /diagnostics text, without ROS (gimbal_friction.streams.diagnostics): values, the managed nodes'
state, the estimator's statistics. The nodes turn these into diagnostic_msgs field by field."""

from __future__ import annotations

import math
import subprocess
import sys

from gimbal_friction.streams.diagnostics import (
    ERROR,
    OK,
    WARN,
    Status,
    exact,
    statistics_statuses,
    status,
    value_text,
    with_lifecycle_state,
)


def test_values_read_as_the_nodes_publish_them():
    s = status('gimbal_friction/feedforward/elevation', WARN, 'stale temperature', 'elevation',
               {'torque_nm': 0.0123456789, 'published': 12, 'last': 'none', 'ok': True, 'nan': math.nan})
    assert s == Status('gimbal_friction/feedforward/elevation', WARN, 'stale temperature', 'elevation',
                       (('torque_nm', '0.0123457'), ('published', '12'), ('last', 'none'), ('ok', 'True'),
                        ('nan', 'nan')))
    assert value_text(1e-12) == '1e-12' and exact(1e-12) == '1e-12' and float(exact(0.1 + 0.2)) == 0.1 + 0.2


def test_a_managed_node_says_its_state_in_the_first_status_and_every_message_while_not_active():
    statuses = [status('a', OK, 'ok', '', {'n': 1}), status('b', ERROR, 'unconfigured: refused', '', {})]
    inactive = with_lifecycle_state(statuses, 'unconfigured')
    assert [x.message for x in inactive] == ['unconfigured: ok', 'unconfigured: refused']   # prefixed once
    assert inactive[0].values == (('n', '1'), ('lifecycle_state', 'unconfigured')) and inactive[1].values == ()
    active = with_lifecycle_state(statuses, 'active')
    assert [x.message for x in active] == ['ok', 'unconfigured: refused']
    assert active[0].values[-1] == ('lifecycle_state', 'active')
    assert with_lifecycle_state(statuses, None) == statuses   # a plain node: unchanged
    assert with_lifecycle_state([], 'inactive') == []


def test_statistics_read_back_exactly():
    rec = {'joint': 'azimuth', 'direction': 1, 'plateau_c': None, 'count': 7, 'mean_nm': 0.1 + 0.2,
           'std_nm': 1 / 3, 'ripple_nm': 0.0, 'min_position': -0.5, 'max_position': 2 / 3}
    (s,) = statistics_statuses([rec])
    assert s.name == 'gimbal_friction/estimator/statistics/azimuth/+1/unknown' and s.level == OK
    values = dict(s.values)
    assert float(values['mean_nm']) == 0.1 + 0.2 and float(values['max_position_rad']) == 2 / 3
    assert values['count'] == '7' and values['direction'] == '+1' and values['plateau_c'] == 'unknown'
    assert s.hardware_id == 'azimuth' and s.message == 'mean 300 N*mm, 7 samples'


def test_the_module_loads_no_ros():
    code = ('import sys, gimbal_friction.streams.diagnostics; print(sorted(m for m in sys.modules '
            'if m.split(".")[0] in ("rclpy", "diagnostic_msgs", "rosidl_runtime_py")))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '[]', out.stdout
