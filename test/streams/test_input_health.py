"""The words of an input that delivers nothing (no rclpy), and the qos_overrides parameters the config accepts."""

from __future__ import annotations

import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.config.loader import check_config_files, check_parameter_names
from gimbal_friction.streams.input_health import InputWatch, PublisherFacts

JS_TYPE = 'sensor_msgs/msg/JointState'


def watch(required=True):
    return InputWatch('/joint_states', JS_TYPE, required=required, timeout_s=2.0, now_s=0.0)


def test_wrong_type_and_incompatible_qos_are_named_for_every_input():
    w = watch(required=False)
    facts = [PublisherFacts('/a', 'std_msgs/msg/String', 'reliable'),
             PublisherFacts('/b', JS_TYPE, 'best_effort', 'Best effort publisher and reliable subscription'),
             PublisherFacts('/c', JS_TYPE, 'reliable')]
    problems = w.observe(100.0, 0, facts, 'reliable')
    assert problems == [
        '/joint_states: publisher /a sends std_msgs/msg/String, this node reads sensor_msgs/msg/JointState '
        '(nothing of it arrives)',
        '/joint_states: publisher /b (best_effort) cannot match this reliable subscription: Best effort publisher '
        'and reliable subscription (set qos_overrides./joint_states.subscription.reliability)']
    # an optional input is never reported for silence
    assert w.observe(200.0, 0, facts[2:]) == [] and w.observe(300.0, 0, []) == []


def test_silence_of_a_required_input_after_its_timeout():
    w = watch()
    ok = [PublisherFacts('/c', JS_TYPE, 'reliable')]
    assert w.observe(2.0, 0, []) == []                                    # not longer than the timeout yet
    assert w.observe(2.5, 0, []) == ['/joint_states: no publisher for 2.5 s']
    assert w.observe(3.0, 0, ok) == []                                    # a publisher appeared: time again
    assert w.observe(5.5, 0, ok) == ['/joint_states: 1 publisher matched but nothing received for 2.5 s']
    assert w.observe(6.0, 3, ok) == []                                    # messages arrived
    assert w.observe(7.0, 3, ok) == []
    assert w.observe(9.0, 3, []) == ['/joint_states: no publisher for 3 s']  # it left: silent since the last one
    two = ok + [PublisherFacts('/d', JS_TYPE, 'best_effort')]
    assert w.observe(9.5, 3, two) == [] and w.observe(12.0, 3, two)[0].startswith('/joint_states: 2 publishers')


def test_qos_overrides_are_accepted_from_a_parameter_file(tmp_path):
    path = tmp_path / 'qos.yaml'
    path.write_text('/**:\n  ros__parameters:\n    qos_overrides:\n      /joint_states:\n        subscription:\n'
                    '          reliability: best_effort\n          depth: 50\n          history: keep_last\n'
                    '      /gimbal/friction/feedforward:\n        publisher:\n          reliability: reliable\n')
    check_config_files([path])   # refused as unknown parameters before


@pytest.mark.parametrize(('name', 'value', 'rule'), [
    ('qos_overrides./joint_states.subscription.durability', 'volatile', 'not overridable'),
    ('qos_overrides./joint_states.subscription.reliability', 'sometimes', 'must be one of reliable, best_effort'),
    ('qos_overrides./joint_states.subscription.depth', 0, 'whole number >= 1'),
    ('qos_overrides./joint_states.subscription.depth', 'ten', 'whole number >= 1'),
    ('qos_overrides.joint_states.subscription.depth', 10, 'fully qualified (/joint_states)'),
    ('qos_overrides./joint_states.reader.depth', 10, '<publisher|subscription>'),
])
def test_a_qos_override_the_nodes_cannot_take_is_refused(name, value, rule):
    with pytest.raises(ConfigError) as err:
        check_parameter_names('friction_feedforward', {name: value}, (), {name: 'x.yaml'})
    assert rule in str(err.value) and name in str(err.value) and '(from x.yaml)' in str(err.value)
