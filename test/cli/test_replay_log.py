"""The replay's residual log (bulk CDR, ``write_raw_many``) has the live logger's topics and layouts, with two axes:
one feedforward message per joint-state message carrying every configured joint (as the node publishes), one
measurement, detail, residual and residual detail per accepted sample, and only the three input topics."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from gimbal_friction.chamber.replay import replay_bag
from gimbal_friction.config.loader import render_parameter_file
from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import default_typestore
from gimbal_friction.recording.bag_write import make_joint_state, make_temperature, write_chamber_bag
from gimbal_friction.recording.residual_read import read_residual_rows
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS

JOINTS = ['elevation', 'azimuth']


def two_joint_bag(path: Path, *, same_topic: bool = False) -> Path:
    """Two joints moving at the commanded speed; some currents logged late; ties in log time."""
    rng = np.random.default_rng(3)
    msgs = []
    js_topic = '/js' if same_topic else topics.JOINT_STATES
    cur_topic = '/js' if same_topic else topics.MOTOR_CURRENT
    for i in range(240):
        t = 1_000_000_000 + i * 20_000_000
        v = 2 * math.pi / 180 * (1 if (i // 120) % 2 == 0 else -1)
        if i % 10 == 0:
            msgs.append((topics.TEMPERATURE, topics.TEMPERATURE_TYPE, t, make_temperature(t, -40.0 + i / 100)))
        names = JOINTS if i % 7 else JOINTS[::-1]
        msgs.append((js_topic, topics.JOINT_STATE_TYPE, t,
                     make_joint_state(t, names, [0.01 * (i % 50) / 50] * 2, [v, 0.9 * v])))
        late = int(rng.integers(0, 3)) * 20_000_000 if i % 5 == 0 else 1
        msgs.append((cur_topic, topics.JOINT_STATE_TYPE, t + late,
                     make_joint_state(t, names, effort=[0.06 * np.sign(v), 0.05 * np.sign(v)])))
    msgs.sort(key=lambda m: m[2])
    return write_chamber_bag(path, msgs)


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture
def two_axes(tmp_path):
    cfg = tmp_path / 'two_axes.yaml'
    cfg.write_text(render_parameter_file(axes=JOINTS))
    return cfg


def decoded(folder: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    with AnyReader([folder], default_typestore=default_typestore()) as reader:
        for conn, log_ns, data in reader.messages():
            out.setdefault(conn.topic, []).append((log_ns, reader.deserialize(data, conn.msgtype)))
    return out


@pytest.mark.parametrize('log_inputs', [True, False])
def test_two_joints_and_late_currents(tmp_path, two_axes, log_inputs):
    bag = two_joint_bag(tmp_path / 'bag')
    result = replay_bag(bag, tmp_path / 'out', config_paths=[two_axes], log_inputs=log_inputs)
    assert set(result.measurements.joint.tolist()) == set(JOINTS)  # both joints measured
    log = decoded(tmp_path / 'out' / 'residuals')
    ff = log[topics.FEEDFORWARD]
    assert len(ff) == 240 and all(list(m.name) == JOINTS for _, m in ff)     # configured order, both joints
    n = len(result.measurements)
    for topic in (topics.MEASURED, topics.MEASURED_DETAIL, topics.RESIDUAL, topics.RESIDUAL_DETAIL):
        assert len(log[topic]) == n, topic
    inputs = {topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT}
    assert set(log) - {topics.FEEDFORWARD, topics.MEASURED, topics.MEASURED_DETAIL, topics.RESIDUAL,
                       topics.RESIDUAL_DETAIL} == (inputs if log_inputs else set())
    for topic, msgs in log.items():   # every topic in log-time order
        assert [t for t, _ in msgs] == sorted(t for t, _ in msgs), topic
    rows, _ = read_residual_rows([tmp_path / 'out' / 'residuals'])
    order = np.lexsort((rows.joint, rows.stamp_s))
    ref = np.lexsort((result.rows.joint, result.rows.stamp_s))
    np.testing.assert_array_equal(rows.matrix()[order], result.rows.matrix()[ref])
    details = np.array([m.data for _, m in log[topics.MEASURED_DETAIL]])
    assert details.shape == (n, len(MEASUREMENT_FIELDS))


def test_one_bag_topic_feeding_two_contract_topics(tmp_path, two_axes):
    bag = two_joint_bag(tmp_path / 'bag', same_topic=True)
    topic_map = {topics.JOINT_STATES: '/js', topics.MOTOR_CURRENT: '/js'}
    result = replay_bag(bag, tmp_path / 'out', config_paths=[two_axes], topic_map=topic_map)
    log = decoded(tmp_path / 'out' / 'residuals')
    assert len(log[topics.JOINT_STATES]) == len(log[topics.MOTOR_CURRENT]) == 480   # the bag topic, both roles
    assert len(result.measurements) > 0
