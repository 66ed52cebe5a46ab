"""The three node adapters fed hostile message streams directly (in this process, no DDS in between): thousands of
generated messages through the very callbacks the executables run.

For every node: no callback raises; every output is finite (the feedforward within its clamp, the estimator's
friction signed like the motion, the log's rows credible); ``/diagnostics`` names the cause while it happens and
is back to OK one period after the cause stopped.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS

pytestmark = pytest.mark.ros  # real rclpy nodes and contexts on an isolated domain
OK, WARN, ERROR = b'\x00', b'\x01', b'\x02'
V = 2 * math.pi / 180 / 3 * 3
ANY = st.floats(allow_nan=True, allow_infinity=True)
VALUE = st.one_of(st.floats(-0.1, 0.1), ANY, st.sampled_from([1e154, -1e308, 5e-324, 0.0]))
NAME = st.sampled_from(['elevation', 'elevation', 'azimuth', 'bogus', ''])
STAMP = st.one_of(st.integers(0, 2000), st.sampled_from([0, 2**31 - 1, -2**31, 10**9]))


@st.composite
def joint_state_msg(draw: st.DrawFn) -> JointState:
    names = draw(st.lists(NAME, max_size=4))
    def arr() -> list[float]:
        n = len(names) if draw(st.integers(0, 4)) else draw(st.integers(0, 5))
        return draw(st.lists(VALUE, min_size=n, max_size=n))
    msg = JointState(name=names, position=arr(), velocity=arr(), effort=arr())
    msg.header.stamp = Time(sec=draw(STAMP), nanosec=draw(st.integers(0, 999_999_999)))
    return msg


@st.composite
def temperature_msg(draw: st.DrawFn) -> Temperature:
    msg = Temperature(temperature=draw(st.one_of(st.floats(-70, 130), ANY, st.sampled_from([-273.0, 999.0]))))
    msg.header.stamp = Time(sec=draw(STAMP))
    return msg


def statuses(node: Any) -> list[Any]:
    node.pub_diag.clear()
    node.publish_diagnostics()
    return list(node.pub_diag.messages[-1].status)


def values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def clean_temperature(sec: int, t_c: float = -20.0) -> Temperature:
    msg = Temperature(temperature=t_c)
    msg.header.stamp = Time(sec=sec)
    return msg


def clean_joint_state(sec: int, nanosec: int = 0, v: float = V, position: float = 0.01) -> JointState:
    msg = JointState(name=['elevation'], position=[position], velocity=[v])
    msg.header.stamp = Time(sec=sec, nanosec=nanosec)
    return msg


# ------------------------------------------------------------------------------------------------ feedforward
@pytest.fixture(scope='module')
def ff(in_process: Any) -> Any:
    from gimbal_friction.nodes.feedforward import FrictionFeedforward
    return in_process.make(FrictionFeedforward, max_torque_nm=0.004, velocity_source='measured')


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(stream=st.lists(st.one_of(joint_state_msg(), temperature_msg(), st.tuples(st.just('ref'), joint_state_msg())),
                       min_size=1, max_size=25))
@pytest.mark.slow
def test_feedforward_node_survives_hostile_streams(ff, stream):
    ff.pub_ff.clear()
    ff.pub_cmd.clear()
    for msg in stream:
        if isinstance(msg, tuple):
            ff.on_reference(msg[1])
        elif isinstance(msg, Temperature):
            ff.on_temperature(msg)
        else:
            ff.on_joint_state(msg)
    for out in ff.pub_ff.messages:
        assert len(out.name) == len(out.effort) and set(out.name) <= {'elevation'}
        assert all(math.isfinite(e) and abs(e) <= 0.004 for e in out.effort)
    for out in ff.pub_cmd.messages:
        assert len(out.data) == 1 and all(math.isfinite(e) and abs(e) <= 0.004 for e in out.data)
    assert set(ff.ff.references) <= {'elevation'}           # hostile names are not kept
    assert not getattr(ff, 'callback_errors', {})


def test_feedforward_diagnostics_name_the_cause_and_return_to_ok(ff):
    ff.on_temperature(clean_temperature(3000))
    ff.on_joint_state(clean_joint_state(3000))
    statuses(ff)                                      # report what the hostile streams left
    bad = JointState(name=['elevation', 'elevation', 'bogus'], velocity=[V, -V])
    bad.header.stamp = Time(sec=3000)
    ff.on_joint_state(bad)
    ff.on_temperature(clean_temperature(3000, math.nan))
    ff.on_joint_state(clean_joint_state(3000, v=5.0))      # saturates
    (st1,) = [s for s in statuses(ff) if s.name == 'gimbal_friction/feedforward/elevation']
    assert st1.level == WARN
    for cause in ('value/name length mismatch', 'non-finite temperature', 'output saturated'):
        assert cause in st1.message, st1.message
    vals = values(st1)
    assert int(vals['rejected_joint_state: value/name length mismatch']) >= 1
    ff.on_temperature(clean_temperature(3001))
    ff.on_joint_state(clean_joint_state(3001))
    (st2,) = [s for s in statuses(ff) if s.name == 'gimbal_friction/feedforward/elevation']
    assert st2.level == OK and st2.message == 'ok', st2.message
    assert values(st2)['rejected_temperature: non-finite temperature'] == vals['rejected_temperature: '
                                                                               'non-finite temperature']


# ------------------------------------------------------------------------------------------------ estimator
@pytest.fixture(scope='module')
def estimator(in_process: Any) -> Any:
    from gimbal_friction.nodes.estimator import FrictionEstimator
    return in_process.make(FrictionEstimator, method='both', min_dwell_s=0.05)


def feed_clean(node: Any, sec: int, steps: int, sign: float = 1.0) -> None:
    node.on_temperature(clean_temperature(sec))
    for k in range(steps):
        ns = k * 10_000_000
        node.on_joint_state(clean_joint_state(sec + ns // 10**9, ns % 10**9, sign * V))
        cur = JointState(name=['elevation'], effort=[sign * 0.06])
        cur.header.stamp = Time(sec=sec + ns // 10**9, nanosec=ns % 10**9)
        node.on_current(cur)
    node.process()


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(stream=st.lists(st.tuples(st.sampled_from(['js', 'cur', 't', 'process']), joint_state_msg(),
                                 temperature_msg()), min_size=1, max_size=30))
@pytest.mark.slow
def test_estimator_node_survives_hostile_streams(estimator, stream):
    estimator.pub_measured.clear()
    estimator.pub_detail.clear()
    for kind, js, t in stream:
        if kind == 'js':
            estimator.on_joint_state(js)
        elif kind == 'cur':
            estimator.on_current(js)
        elif kind == 't':
            estimator.on_temperature(t)
        else:
            estimator.process()
    estimator.process()
    for m in estimator.pub_measured.messages:
        assert m.name == ['elevation'] and math.isfinite(m.effort[0]) and m.effort[0] * m.velocity[0] > 0.0
    for d in estimator.pub_detail.messages:
        assert len(d.data) == len(MEASUREMENT_FIELDS) and all(math.isfinite(x) or math.isnan(x) for x in d.data)
    estimator.publish_statistics()
    assert not getattr(estimator, 'callback_errors', {})


def test_estimator_diagnostics_name_the_cause_and_return_to_ok(estimator):
    sec = 5000
    feed_clean(estimator, sec, 100)
    statuses(estimator)
    future = clean_joint_state(sec + 10**6)                 # one joint state stamped 11 days ahead
    estimator.on_joint_state(future)
    bad = JointState(name=['elevation'], effort=[math.inf])
    bad.header.stamp = Time(sec=sec + 2)
    estimator.on_current(bad)
    estimator.process()
    feed_clean(estimator, sec + 2, 100)                      # back to normal stamps: the stream restarts
    by_name = {s.name: s for s in statuses(estimator)}
    joint = by_name['gimbal_friction/estimator/elevation']
    assert joint.level == WARN
    assert 'stream restarted (stamp jumped back)' in joint.message and 'non-finite' in joint.message
    accepted = int(values(joint)['accepted'])
    feed_clean(estimator, sec + 4, 100)
    by_name = {s.name: s for s in statuses(estimator)}
    joint = by_name['gimbal_friction/estimator/elevation']
    assert joint.level == OK, joint.message
    assert int(values(joint)['accepted']) > accepted            # accepting again, not locked up
    node_status = by_name['gimbal_friction/estimator']
    assert node_status.level == OK, node_status.message


# ------------------------------------------------------------------------------------------------ residual logger
@pytest.fixture(scope='module')
def logger(in_process: Any, tmp_path_factory: pytest.TempPathFactory) -> Any:
    from gimbal_friction.nodes.residual_logger import ResidualLogger
    return in_process.make(ResidualLogger, output_dir=str(tmp_path_factory.mktemp('residuals')),
                           pairing_timeout_s=0.001)


def detail(sec: int, values: dict[str, float], label: str = 'elevation', n: int | None = None) -> bytes:
    row = [0.0] * len(MEASUREMENT_FIELDS)
    base = {'stamp_sec': float(sec), 'position_rad': 0.01, 'velocity_rad_s': V, 'current_a': 0.06,
            'temperature_c': -20.0, 'temperature_fresh': 1.0, 'friction_nm': 0.0025,
            'torque_constant_nm_per_a': 0.05}
    for k, v in {**base, **values}.items():
        row[MEASUREMENT_FIELDS.index(k)] = v
    msg = Float64MultiArray(data=row[:n] if n is not None else row)
    msg.layout.dim = [MultiArrayDimension(label=label, size=len(row), stride=len(row))]
    return serialize_message(msg)


def feedforward(sec: int, effort: float, names: tuple[str, ...] = ('elevation',)) -> bytes:
    msg = JointState(name=list(names), effort=[effort] * len(names))
    msg.header.stamp = Time(sec=sec)
    return serialize_message(msg)


FIELD = st.sampled_from(list(MEASUREMENT_FIELDS))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(stream=st.lists(st.one_of(
    st.tuples(st.just('detail'), st.integers(1, 3000), st.dictionaries(FIELD, VALUE, max_size=3),
              st.sampled_from(['elevation', 'azimuth', '']), st.sampled_from([None, 0, 5, 14])),
    st.tuples(st.just('ff'), st.integers(1, 3000), VALUE, st.sampled_from([('elevation',), ('elevation', 'elevation'),
                                                                          ('bogus',)]), st.none()),
    st.tuples(st.just('raw'), st.binary(max_size=40), st.none(), st.none(), st.none()),
    st.tuples(st.just('pair'), st.none(), st.none(), st.none(), st.none())), min_size=1, max_size=30))
def test_logger_survives_hostile_streams(logger, stream):
    for kind, a, b, c, d in stream:
        if kind == 'detail':
            logger.on_measured_detail(detail(a, b, c, d))
        elif kind == 'ff':
            logger.on_feedforward(feedforward(a, b, c))
        elif kind == 'raw':
            logger.on_measured_detail(a)
            logger.on_feedforward(a)
        else:
            logger.pair()
    logger.pair(final=True)
    for (joint, b), (n, rms) in logger.stats.rms().items():
        assert joint == 'elevation' and n >= 1 and math.isfinite(rms)
        assert b is None or math.isfinite(b)
    assert not getattr(logger, 'callback_errors', {})
    assert logger.writer is not None and logger.error is None


def test_logger_diagnostics_name_the_cause_and_return_to_ok(logger):
    statuses(logger)
    logger.on_feedforward(feedforward(7000, 1e154))                   # the effort that killed it once
    logger.on_measured_detail(detail(7000, {'friction_nm': 1e154}))
    logger.on_measured_detail(detail(7001, {'stamp_sec': math.nan}))
    logger.pair(final=True)
    top = statuses(logger)[0]
    assert top.level == WARN
    for cause in ('feedforward not finite or not credible', 'not finite or not credible',
                  'measured_detail with an invalid stamp or method'):
        assert cause in top.message, top.message
    logged = int(values(top)['residuals_logged'])
    logger.on_feedforward(feedforward(7002, 0.002))
    logger.on_measured_detail(detail(7002, {}))
    logger.pair()
    sts = statuses(logger)
    assert sts[0].level == OK and sts[0].message == 'logging', sts[0].message
    assert int(values(sts[0])['residuals_logged']) == logged + 1
    rms = [s for s in sts if s.name == 'gimbal_friction/residual_logger/elevation']
    assert rms and all(v == 'nan' or math.isfinite(float(v)) for v in values(rms[0]).values())
    assert all(v != 'nan' for k, v in values(rms[0]).items() if k.startswith('rms'))


def test_logger_closes_a_readable_log_whatever_it_was_fed(in_process: Any, tmp_path: Path):
    from gimbal_friction.nodes.residual_logger import ResidualLogger
    from gimbal_friction.recording.residual_read import read_residual_rows
    node = in_process.make(ResidualLogger, output_dir=str(tmp_path / 'log'), pairing_timeout_s=100.0)
    node.on_feedforward(feedforward(10, 0.002))
    node.on_measured_detail(detail(10, {}))
    node.on_measured_detail(detail(11, {'stamp_sec': 1e300}))          # refused, not left waiting
    node.on_measured_detail(detail(12, {}))                              # waits for its feedforward
    node.close()                                                         # logs the waiting one without it
    rows, log = read_residual_rows(tmp_path / 'log')
    assert len(rows) == 2 and rows.predicted_nm[0] == 0.002 and np.isnan(rows.predicted_nm[1])
    assert not log.truncated_files


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(statuses_in=st.lists(st.tuples(
    st.sampled_from(['gimbal_friction/chamber_replay', 'gimbal_friction/residual_logger', '']),
    st.dictionaries(st.sampled_from(['state', 'published: /joint_states', 'publisher_gid: /joint_states',
                                     'published: /gimbal/temperature', 'published: /elsewhere', 'published: ']),
                    st.one_of(st.sampled_from(['finished', 'playing', '0a0b', 'zz', '-1', '1e400', '9' * 30, '']),
                              st.integers(-5, 10**6).map(str), st.text(max_size=8)), max_size=5)),
    min_size=1, max_size=20))
@pytest.mark.slow
def test_logger_survives_hostile_publisher_counts(logger, statuses_in):
    """What a publisher says it sent (/diagnostics) is untrusted: any status, any value, no exception; an unusable
    'finished' status is refused and counted; the counts waiting to be taken stay bounded."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from gimbal_friction.nodes.residual_logger import MAX_PENDING_COUNTS
    before = dict(logger.refused)
    msg = DiagnosticArray(status=[DiagnosticStatus(name=name, values=[KeyValue(key=k, value=v) for k, v in kv.items()])
                                  for name, kv in statuses_in])
    logger.on_diagnostics(msg)
    logger.take_sent_counts()
    assert len(logger._sent_counts) <= MAX_PENDING_COUNTS
    reason = 'publisher status without a usable count of what it sent'
    assert logger.refused.get(reason, 0) >= before.get(reason, 0)
    unusable = DiagnosticStatus(name='gimbal_friction/chamber_replay', values=[
        KeyValue(key='state', value='finished'), KeyValue(key='published: /elsewhere', value='5'),
        KeyValue(key='published: /joint_states', value='7'), KeyValue(key='publisher_gid: /joint_states', value='zz')])
    counted = logger.refused.get(reason, 0)
    logger.on_diagnostics(DiagnosticArray(status=[unusable]))  # not a topic logged here; a gid that is not hex
    assert logger.refused[reason] == counted + 1
    for value in logger.inputs.values().values():
        assert value == 'unknown' or int(value) >= 0
    assert not getattr(logger, 'callback_errors', {})


# ------------------------------------------------------------------------------------------------ learning counts
def test_every_measured_detail_received_is_counted_used_or_refused(in_process: Any):
    """received = samples_used + samples_refused (per reason) whatever happens: hostile messages, messages while
    learning is off, a reset and a model change with samples still pending (discarded, counted)."""
    from rclpy.parameter import Parameter

    from gimbal_friction.nodes.feedforward import FrictionFeedforward
    from robustness.nodes_harness import hostile_details
    # (the refits in this process: the test steps the learner itself and reads its cells at once)
    node = in_process.make(FrictionFeedforward, learning_enabled=True, learning_step_period_s=3600.0,
                           learning_fit_worker='inline')
    now = node.get_clock().now()
    temp = Temperature(temperature=-40.0)
    temp.header.stamp = now.to_msg()
    node.on_temperature(temp)
    sec = now.nanoseconds // 10**9
    fed = 0

    def feed(n: int) -> None:
        nonlocal fed
        for msg in hostile_details(n, sec):
            node.on_measured_detail(msg)
        fed += n

    def learning() -> dict[str, str]:
        (st,) = [s for s in statuses(node) if s.name == 'gimbal_friction/feedforward/learning']
        return values(st)

    feed(800)
    first = learning()
    assert 0 < int(first['samples_pending']) == int(first['samples_used']) < fed    # waiting for the next step
    node.reset_learning()                                        # the pending samples: discarded, still counted
    v = learning()
    assert v['samples_used'] == first['samples_used'] and v['samples_discarded'] == first['samples_pending']
    assert v['samples_pending'] == '0'
    assert node.set_parameters([Parameter('learning_enabled', value=False)])[0].successful
    feed(40)
    assert node.set_parameters([Parameter('learning_enabled', value=True)])[0].successful
    feed(400)
    pending = int(learning()['samples_pending'])
    assert pending > 0
    # another model: a new correction
    assert node.set_parameters([Parameter('model.walther_a', value=8.7)])[0].successful
    v = learning()
    assert int(v['samples_discarded']) == int(first['samples_pending']) + pending and v['samples_pending'] == '0'
    refused = {k: int(x) for k, x in v.items() if k.startswith('refused: ')}
    assert refused['refused: learning off'] == 40 and sum(refused.values()) == int(v['samples_refused'])
    assert int(v['samples_used']) + int(v['samples_refused']) == fed, v
    assert not getattr(node, 'callback_errors', {})
    # what the hostile stream left is published on /gimbal/friction/correction as finite numbers only
    feed(800)
    node.keeper.learner.flush()                                  # (learned: the cells have data, none scored yet)
    node.pub_correction.clear()
    node.publish_correction()
    (arr,) = node.pub_correction.messages
    cells = [s for s in arr.status if s.name.count('/') == 4]
    assert cells and any(values(s)['rms_model_nm'] == 'not scored' for s in cells)
    for s in arr.status:
        for kv in s.values:
            assert 'nan' not in kv.value.lower() and 'inf' not in kv.value.lower(), (s.name, kv.key, kv.value)
