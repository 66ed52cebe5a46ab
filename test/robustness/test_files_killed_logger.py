"""``residual_logger`` (the real node, real DDS) killed with SIGKILL at random moments: what it received more than one
flush interval before the kill is on disk, and ``gimbal-friction recover`` makes the killed folder a complete log.

The test depends only on the node's contract: its input topics (joint states, feedforward, measured friction and
its detail) and
its parameters ``output_dir`` and ``flush_period_s``. The loss bound is checked against the wall clock with a margin
for a shared machine (MARGIN_S): what was published at least FLUSH_S + MARGIN_S before the kill must be recovered.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from gimbal_friction.recording import topics
from gimbal_friction.recording.residual_read import iter_residual_log, read_residual_rows

pytestmark = pytest.mark.ros

FLUSH_S = 0.25  # flush_period_s of the node [s]
MARGIN_S = 1.0  # scheduling and DDS delivery on a loaded 2-core machine [s]
RATE_HZ = 20.0  # samples per second [1/s]: a few KiB per second, so only the timed flushes put data on disk


def joint_state(i: int, effort: float) -> object:
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import JointState

    msg = JointState(name=['elevation'], position=[0.01], velocity=[0.05], effort=[effort])
    msg.header.stamp = Time(sec=1000 + i // 1000, nanosec=(i % 1000) * 1_000_000)
    return msg


def measured_detail(i: int, friction: float) -> object:
    """The estimator's measured_detail of sample ``i`` (MEASUREMENT_FIELDS)."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS

    values = {'stamp_sec': 1000 + i // 1000, 'stamp_nanosec': (i % 1000) * 1_000_000, 'position_rad': 0.01,
              'velocity_rad_s': 0.05, 'current_a': friction / 0.05, 'temperature_c': 20.0, 'temperature_fresh': 1.0,
              'friction_nm': friction, 'torque_constant_nm_per_a': 0.05}
    n = len(MEASUREMENT_FIELDS)
    msg = Float64MultiArray(data=[float(values.get(f, 0.0)) for f in MEASUREMENT_FIELDS])
    msg.layout.dim = [MultiArrayDimension(label='elevation', size=n, stride=n)]
    return msg


def sample_index(stamp_ns: int) -> int:
    return int(round((stamp_ns - 1000 * 1_000_000_000) / 1_000_000))


@pytest.mark.slow
@pytest.mark.parametrize('seed', [1, 2])
def test_sigkill_loses_at_most_one_flush_interval(tmp_path: Path, spawn, probe, rb, seed: int) -> None:
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    rng = np.random.default_rng(seed)
    kill_after_s = float(rng.uniform(2.0, 3.5))  # a random moment, several flush intervals in
    folder = tmp_path / 'log'
    node = spawn('residual_logger', '--ros-args', '-p', f'output_dir:={folder}', '-p', f'flush_period_s:={FLUSH_S}')
    pubs = {t: probe.publisher(JointState, t) for t in (topics.JOINT_STATES, topics.FEEDFORWARD, topics.MEASURED)}
    pubs[topics.MEASURED_DETAIL] = probe.publisher(Float64MultiArray, topics.MEASURED_DETAIL)
    for topic, pub in pubs.items():
        probe.spin_until(lambda pub=pub: pub.get_subscription_count() >= 1, what=f'the logger on {topic}')
    sent_at: list[float] = []  # wall time of each sample's publication [s]
    start = time.monotonic()
    i = 0
    while time.monotonic() - start < kill_after_s:
        if time.monotonic() - start >= i / RATE_HZ:
            pubs[topics.JOINT_STATES].publish(joint_state(i, 0.0))
            pubs[topics.FEEDFORWARD].publish(joint_state(i, 3e-3))
            pubs[topics.MEASURED].publish(joint_state(i, 3.1e-3))
            pubs[topics.MEASURED_DETAIL].publish(measured_detail(i, 3.1e-3))
            sent_at.append(time.monotonic())
            i += 1
        probe.executor.spin_once(timeout_sec=0.001)
    killed_at = time.monotonic()
    node.proc.send_signal(signal.SIGKILL)
    node.proc.wait(10)
    assert not (folder / 'metadata.yaml').exists()  # killed: no clean close

    fixed = tmp_path / 'fixed'
    run = rb.run('recover', str(folder), '--out', str(fixed))
    assert run.code == 0, run.err
    with AnyReader([fixed]) as reader:  # a complete rosbag2 folder now
        assert reader.message_count > 0
    received = sorted(sample_index(m.msg.header.stamp.sec * 1_000_000_000 + m.msg.header.stamp.nanosec)
                      for m in iter_residual_log(fixed, [topics.JOINT_STATES]))
    assert len(set(received)) == len(received) and set(received) <= set(range(i))  # nothing invented
    must_have = [k for k, t in enumerate(sent_at) if t <= killed_at - FLUSH_S - MARGIN_S]
    assert len(must_have) >= 10, 'the kill came too early to test anything'
    missing = sorted(set(must_have) - set(received))
    assert not missing, f'{len(missing)} samples published more than {FLUSH_S + MARGIN_S} s before the kill lost'
    rows, report = read_residual_rows(fixed)  # the residual rows, paired before the kill, read back
    assert len(rows) > 0 and report.truncated_files == []
    stamps = np.asarray(rows.stamp_s) - 1000.0
    assert set(np.round(stamps * 1000).astype(int).tolist()) <= set(received)
