"""The replay's residual log (bulk CDR, merged with argsort, ``write_raw_many``) equals the per-message writer's.

The reference below is the straightforward way: a rosbags message object per output message, serialized by the
type store, merged with ``heapq.merge`` over generators and written one by one. Both logs must be the same files,
byte for byte, also where the streams are out of log-time order (two joints, late currents) and where one bag
topic feeds two contract topics.
"""

from __future__ import annotations

import heapq
import math
from pathlib import Path

import numpy as np
import pytest

from gimbal_friction.config import render_parameter_file
from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import default_typestore, make_float64_multi_array, make_joint_state, \
    make_temperature, open_chamber_bag, write_chamber_bag
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.replay import replay_bag

JOINTS = ['elevation', 'azimuth']


def reference_log(folder: Path, bag_path: Path, result, *, topic_map=None, log_inputs: bool = True) -> None:
    ff, est, pred, temp, comps = (result.feedforward, result.estimate, result.predicted_nm,
                                  result.prediction_temperature_c, result.m_components_nm)
    arrays = open_chamber_bag(bag_path, topic_map).read_arrays()
    js_log = dict(zip(np.asarray(arrays.joint_states.stamp_ns).tolist(), arrays.joint_states.log_time_ns.tolist()))
    est_log = [js_log.get(int(s), 0) for s in est.stamp_ns.tolist()]
    js_type, fa_type = topics.JOINT_STATE_TYPE, topics.FLOAT64_MULTI_ARRAY_TYPE
    ff_iter = ((int(ff.log_time_ns[i]), topics.FEEDFORWARD, js_type,
                make_joint_state(int(ff.stamp_ns[i]), [str(ff.joint[i])], effort=[float(ff.torque_nm[i])]))
               for i in range(len(ff.torque_nm)))

    def measured_iter():
        for i in range(len(est)):
            if not math.isfinite(pred[i]):
                continue
            j, stamp, log = str(est.joint[i]), int(est.stamp_ns[i]), est_log[i]
            pos, vel, meas = float(est.position_rad[i]), float(est.velocity_rad_s[i]), float(est.friction_nm[i])
            yield log, topics.MEASURED, js_type, make_joint_state(stamp, [j], [pos], [vel], [meas])
            res = meas - float(pred[i])
            yield log, topics.RESIDUAL, js_type, make_joint_state(stamp, [j], [pos], [vel], [res])
            detail = [stamp * 1e-9, float(temp[i]), pos, vel, float(est.current_a[i]), meas, float(pred[i]),
                      float(comps[i, 0]), float(comps[i, 1]), float(comps[i, 2]), res]
            yield log, topics.RESIDUAL_DETAIL, fa_type, make_float64_multi_array(detail, j)

    streams = [heapq.merge(ff_iter, measured_iter(), key=lambda m: m[0])]
    if log_inputs:
        bag = open_chamber_bag(bag_path, topic_map)
        streams.append((r.log_time_ns, r.topic, r.msgtype, r.data) for r in bag.iter_raw())
    with ResidualLogWriter(folder, flush_interval_s=None, chunk_size=1 << 20, typestore=default_typestore()) as w:
        for log_ns, topic, msgtype, msg in heapq.merge(*streams, key=lambda m: m[0]):
            if isinstance(msg, bytes):
                w.write_raw(topic, msgtype, log_ns, msg)
            else:
                w.write(topic, msgtype, log_ns, msg)


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


@pytest.mark.parametrize('log_inputs', [True, False])
def test_two_joints_and_late_currents(tmp_path, two_axes, log_inputs):
    bag = two_joint_bag(tmp_path / 'bag')
    result = replay_bag(bag, tmp_path / 'out', config_paths=[two_axes], log_inputs=log_inputs)
    assert set(result.estimate.joint.tolist()) == set(JOINTS)  # both joints measured
    assert result.messages_out > 1000
    reference_log(tmp_path / 'ref', bag, result, log_inputs=log_inputs)
    assert files(tmp_path / 'out' / 'residuals') == files(tmp_path / 'ref')


def test_one_bag_topic_feeding_two_contract_topics(tmp_path, two_axes):
    bag = two_joint_bag(tmp_path / 'bag', same_topic=True)
    topic_map = {topics.JOINT_STATES: '/js', topics.MOTOR_CURRENT: '/js'}
    result = replay_bag(bag, tmp_path / 'out', config_paths=[two_axes], topic_map=topic_map)
    reference_log(tmp_path / 'ref', bag, result, topic_map=topic_map)
    assert files(tmp_path / 'out' / 'residuals') == files(tmp_path / 'ref')
    assert result.messages_out >= 2 * 480
