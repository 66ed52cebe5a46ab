"""The schemas the residual log writes without a type store are the type store's, and a replay of a plain-CDR bag
builds no type store."""

from __future__ import annotations

from pathlib import Path

import pytest

from gimbal_friction.recording import cdr
from gimbal_friction.recording.cdr import default_typestore
from gimbal_friction.recording.schemas import SCHEMAS

ROOT = Path(__file__).resolve().parents[2]


def test_every_schema_is_the_type_stores():
    store = default_typestore()
    for msgtype, (text, digest) in SCHEMAS.items():
        assert text == store.generate_msgdef(msgtype, ros_version=2)[0], msgtype
        assert digest == store.hash_rihs01(msgtype), msgtype


def test_a_replay_of_the_sample_bag_builds_no_type_store(tmp_path, monkeypatch):
    from gimbal_friction.chamber.replay import replay_bag
    from gimbal_friction.recording.residual_read import read_residual_rows
    built = []
    default_typestore.cache_clear()
    real = cdr.get_typestore
    monkeypatch.setattr(cdr, 'get_typestore', lambda *a: built.append(a) or real(*a))
    try:
        result = replay_bag(ROOT / 'bags' / 'chamber_sample', tmp_path / 'out')
    finally:
        default_typestore.cache_clear()
    assert built == []
    assert result.messages_in > 60_000
    rows, _ = read_residual_rows(tmp_path / 'out' / 'residuals')   # the log reads back (its schemas are valid)
    assert len(rows) > 1000


@pytest.mark.parametrize('msgtype', sorted(SCHEMAS))
def test_a_log_of_message_objects_still_uses_the_type_store(tmp_path, msgtype):
    from gimbal_friction.recording.residual_log import ResidualLogWriter
    msg = {'sensor_msgs/msg/JointState': lambda: cdr.make_joint_state(1, ['elevation'], [0.1], [0.2], [0.3]),
           'sensor_msgs/msg/Temperature': lambda: cdr.make_temperature(1, 20.0),
           'std_msgs/msg/Float64MultiArray': lambda: cdr.make_float64_multi_array([1.0, 2.0], 'x')}[msgtype]()
    with ResidualLogWriter(tmp_path / 'log', flush_interval_s=None) as w:
        w.write('/t', msgtype, 1, msg)
    assert list((tmp_path / 'log').glob('*.mcap'))
