"""CDR: the fast serializers are byte-identical to the rosbags type store; the decoders read what it writes."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.recording.cdr import (
    JointStateColumns,
    default_typestore,
    float64_multi_array_cdr,
    float64_multi_array_cdr_rows,
    float64_multi_array_layout,
    float64_multi_array_rows,
    joint_state_cdr,
    joint_state_cdr_rows,
    make_float64_multi_array,
    make_joint_state,
    make_temperature,
    row_blobs,
    split_rows,
    temperature_from_cdr,
    temperature_rows,
)
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, JOINT_STATE_TYPE, TEMPERATURE_TYPE

NAMES = ['elevation', 'azimuth', 'roll', 'a', 'ab', 'abc', 'abcd', 'joint_with_a_long_name', 'ü-ß', '']
FRAMES = ['', 'g', 'gi', 'gimbal', 'gimbal_base_link', 'bâse']


def ref_joint_state(stamp_ns, names, position=None, velocity=None, effort=None, frame_id=''):
    msg = make_joint_state(stamp_ns, names, position, velocity, effort, frame_id)
    return bytes(default_typestore().serialize_cdr(msg, JOINT_STATE_TYPE))


def ref_multi_array(values, label):
    msg = make_float64_multi_array(values, label)
    return bytes(default_typestore().serialize_cdr(msg, FLOAT64_MULTI_ARRAY_TYPE))


def random_values(rng, k):
    values = rng.normal(size=k) * 10.0 ** rng.integers(-12, 12, size=k)
    specials = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 5e-324])
    mask = rng.random(k) < 0.1
    values[mask] = rng.choice(specials, size=int(mask.sum()))
    return values


def random_stamp(rng):
    return int(rng.integers(-(2**31) * 10**9, (2**31 - 1) * 10**9))


def test_joint_state_equals_type_store_on_random_messages():
    rng = np.random.default_rng(1)
    for _ in range(400):
        n_names = int(rng.integers(0, 5))
        names = [str(x) for x in rng.choice(NAMES, size=n_names)]
        fields = [None if rng.random() < 0.3 else random_values(rng, int(rng.integers(0, 5))) for _ in range(3)]
        frame = str(rng.choice(FRAMES))
        stamp = random_stamp(rng)
        assert joint_state_cdr(stamp, names, *fields, frame_id=frame) == ref_joint_state(stamp, names, *fields,
                                                                                         frame_id=frame)


@pytest.mark.parametrize('stamp', [0, 1, 999_999_999, 1_000_000_000, -1, -1_000_000_001,
                                   (2**31 - 1) * 10**9 + 999_999_999, -(2**31) * 10**9])
def test_joint_state_stamp_edges(stamp):
    assert joint_state_cdr(stamp, ['elevation'], effort=[1.5]) == ref_joint_state(stamp, ['elevation'], effort=[1.5])


def test_empty_joint_state():
    assert joint_state_cdr(0, []) == ref_joint_state(0, [])
    assert joint_state_cdr(5, [], [], [], [], frame_id='x') == ref_joint_state(5, [], [], [], [], frame_id='x')


def test_stamp_out_of_int32_range_is_refused():
    with pytest.raises(ValueError, match='int32'):
        joint_state_cdr(2**31 * 10**9, ['a'])
    with pytest.raises(ValueError, match='int32'):
        joint_state_cdr_rows([0, 2**31 * 10**9], ['a'])


def test_multi_array_equals_type_store_on_random_messages():
    rng = np.random.default_rng(2)
    for _ in range(300):
        values = random_values(rng, int(rng.integers(0, 16)))
        label = str(rng.choice(NAMES))
        assert float64_multi_array_cdr(values, label) == ref_multi_array(values, label)


def test_multi_array_with_several_dims_and_offset():
    store = default_typestore()
    types = store.types
    rng = np.random.default_rng(3)
    for n_dims in range(4):
        dims = [(str(rng.choice(NAMES)), int(rng.integers(0, 9)), int(rng.integers(0, 99))) for _ in range(n_dims)]
        values = random_values(rng, int(rng.integers(0, 7)))
        layout = types['std_msgs/msg/MultiArrayLayout'](
            dim=[types['std_msgs/msg/MultiArrayDimension'](label=a, size=b, stride=c) for a, b, c in dims],
            data_offset=7)
        msg = types[FLOAT64_MULTI_ARRAY_TYPE](layout=layout, data=values)
        expected = bytes(store.serialize_cdr(msg, FLOAT64_MULTI_ARRAY_TYPE))
        assert float64_multi_array_cdr(values, dims=dims, data_offset=7) == expected
        rows = float64_multi_array_cdr_rows(values.reshape(1, -1), dims=dims, data_offset=7)
        assert split_rows(rows) == [expected]


def test_joint_state_rows_equal_one_by_one():
    rng = np.random.default_rng(4)
    for trial in range(60):
        n = int(rng.integers(0, 30))
        names = [str(x) for x in rng.choice(NAMES, size=int(rng.integers(0, 4)))]
        ks = [None if rng.random() < 0.3 else int(rng.integers(0, 4)) for _ in range(3)]
        if trial % 5 == 0:  # the (n,) form: one value per message
            ks = [None, None, -1]
        fields = []
        for k in ks:
            if k is None:
                fields.append(None)
            elif k == -1:
                fields.append(random_values(rng, n))
            else:
                fields.append(random_values(rng, n * k).reshape(n, k))
        frame = str(rng.choice(FRAMES))
        stamps = np.array([random_stamp(rng) for _ in range(n)], dtype=np.int64)
        rows = joint_state_cdr_rows(stamps, names, *fields, frame_id=frame)
        got = split_rows(rows)
        assert len(got) == n
        for i in range(n):
            per = [None if f is None else np.atleast_1d(f[i]) for f in fields]
            assert got[i] == ref_joint_state(int(stamps[i]), names, *per, frame_id=frame)


def test_multi_array_rows_equal_one_by_one():
    rng = np.random.default_rng(5)
    for k in (0, 1, 2, 11):
        data = random_values(rng, 20 * k).reshape(20, k)
        got = split_rows(float64_multi_array_cdr_rows(data, 'elevation'))
        assert got == [ref_multi_array(row, 'elevation') for row in data]


def test_rows_keep_nan_payloads_bit_for_bit():
    nan_bits = np.array([0x7FF8000000000001, 0xFFF0000000000123], dtype=np.uint64).view(np.float64)
    rows = joint_state_cdr_rows([1, 2], ['a'], effort=nan_bits)
    for i, raw in enumerate(split_rows(rows)):
        assert raw == ref_joint_state(i + 1, ['a'], effort=nan_bits[i : i + 1])
        assert raw[-8:] == nan_bits[i : i + 1].tobytes()


def test_row_blobs_in_an_object_array_are_the_rows_bytes_trailing_nuls_included():
    # a multi-array row ends in its last double: zeros give rows ending in NUL bytes, which a bytes dtype would drop
    data = np.zeros((5, 3))
    data[1, 2] = 1.5
    rows = float64_multi_array_cdr_rows(data, 'elevation')
    pool = np.empty((5, 2), dtype=object)
    pool[:, 1] = row_blobs(rows)
    pool[np.array([3, 0]), 0] = row_blobs(rows[[3, 0]])
    assert pool[:, 1].tolist() == split_rows(rows) == [ref_multi_array(row, 'elevation') for row in data]
    assert pool[0, 0] == pool[0, 1] and pool[3, 0] == pool[3, 1] and pool[1, 0] is None
    assert all(type(x) is bytes for x in pool[:, 1].tolist())
    assert pool[0, 1].endswith(bytes(8))


def test_empty_batches():
    assert split_rows(joint_state_cdr_rows([], ['a'], effort=np.zeros((0, 1)))) == []
    assert split_rows(float64_multi_array_cdr_rows(np.zeros((0, 11)), 'a')) == []


def test_shape_mismatch_is_refused():
    with pytest.raises(ValueError, match='shape'):
        joint_state_cdr_rows([1, 2], ['a'], effort=[1.0, 2.0, 3.0])


def test_temperature_decoder_reads_what_the_type_store_writes():
    store = default_typestore()
    rng = np.random.default_rng(3)
    for frame in [*FRAMES, 'x' * 13]:
        stamp, value = random_stamp(rng), float(rng.normal() * 50)
        raw = bytes(store.serialize_cdr(make_temperature(stamp, value, frame_id=frame), TEMPERATURE_TYPE))
        assert temperature_from_cdr(raw) == (stamp, value)
        big = bytes(store.serialize_cdr(make_temperature(stamp, value, frame_id=frame), TEMPERATURE_TYPE,
                                        little_endian=False))
        assert temperature_from_cdr(big) is None  # left to the type store
        assert temperature_from_cdr(raw[:-12]) is None  # cut short


def test_multi_array_rows_decode_a_mixed_batch_like_the_type_store():
    rng = np.random.default_rng(4)
    store = default_typestore()
    datas, expected = [], []
    for _ in range(500):
        label = str(rng.choice(NAMES))
        values = random_values(rng, int(rng.choice([0, 1, 11, 12, 12, 12, 40])))
        little = rng.random() > 0.05
        msg = make_float64_multi_array(values, label)
        datas.append(bytes(store.serialize_cdr(msg, FLOAT64_MULTI_ARRAY_TYPE, little_endian=bool(little))))
        expected.append((label, values, little))
    datas.append(float64_multi_array_cdr([1.0, 2.0], dims=[('a', 2, 2), ('b', 1, 1)], data_offset=3))
    expected.append(('a', np.array([1.0, 2.0]), True))
    datas.append(b'\x00\x01\x00\x00\xff')  # not a message
    expected.append(None)
    pad = b'junk'
    buffer = pad + b''.join(datas)
    starts = len(pad) + np.cumsum([0] + [len(d) for d in datas[:-1]])
    rows = float64_multi_array_rows(buffer, starts, [len(d) for d in datas])
    seen = np.zeros(len(datas), dtype=bool)
    for index, label, values in rows.blocks:
        assert not seen[index].any()
        seen[index] = True
        for k, row in zip(index.tolist(), values, strict=True):
            assert expected[k] is not None and expected[k][0] == label and expected[k][2]
            np.testing.assert_array_equal(row, expected[k][1])  # bit for bit, NaN included
    others = set(rows.others.tolist())
    assert others == {k for k, e in enumerate(expected) if e is None or not e[2]}
    assert not seen[list(others)].any() and seen.sum() + len(others) == len(datas)


def test_multi_array_rows_make_one_block_per_layout():
    labels = ['elevation', 'azimuth', 'elev']  # 'elevation' and 'azimuth' have the same length
    datas = [float64_multi_array_cdr(np.full(12 - (i % 7 == 0), float(i)), labels[i % 3]) for i in range(300)]
    starts = np.cumsum([0] + [len(d) for d in datas[:-1]])
    rows = float64_multi_array_rows(b''.join(datas), starts, [len(d) for d in datas])
    layouts = {(labels[i % 3], 12 - (i % 7 == 0)) for i in range(300)}
    assert sorted((label, v.shape[1]) for _, label, v in rows.blocks) == sorted(layouts)
    for index, _, values in rows.blocks:
        np.testing.assert_array_equal(values[:, 0], index)


def test_multi_array_layout_refuses_what_is_not_one():
    raw = float64_multi_array_cdr(np.arange(12.0), 'elevation')
    assert float64_multi_array_layout(raw) == ('elevation', 12, 44)
    assert float64_multi_array_layout(raw + b'\x00' * 8) is None  # trailing bytes
    assert float64_multi_array_layout(raw[:-1]) is None
    assert float64_multi_array_layout(b'\x00\x00' + raw[2:]) is None  # big endian: the type store's job


def test_joint_state_columns_decode_a_mixed_batch_like_the_type_store():
    """add_batch reads messages of many layouts (names, frames, value counts, repeated names, values past the
    names), big-endian ones through the type store, and keeps message order."""
    store = default_typestore()
    rng = np.random.default_rng(8)
    names_pool = [['elevation'], ['elevation', 'azimuth'], ['azimuth', 'elevation'], ['elevation', 'elevation'],
                  ['roll'], []]
    datas, expected, logs = [], [], []
    for i in range(600):
        names = names_pool[int(rng.integers(0, len(names_pool)))] if i % 50 else ['ü-ß', 'elevation']
        fields = [None if rng.random() < 0.3 else random_values(rng, int(rng.integers(0, 4))) for _ in range(3)]
        msg = make_joint_state(random_stamp(rng), names, *fields, frame_id=str(rng.choice(FRAMES)))
        datas.append(bytes(store.serialize_cdr(msg, JOINT_STATE_TYPE, little_endian=bool(i % 17))))
        expected.append(msg)
        logs.append(1000 + i)
    pad = b'xyz'
    buffer = pad + b''.join(datas)
    starts = len(pad) + np.cumsum([0] + [len(d) for d in datas[:-1]])
    columns = JointStateColumns()
    decoded = []

    def decode(k):
        decoded.append(k)
        return store.deserialize_cdr(datas[k], JOINT_STATE_TYPE)

    half = 300
    columns.add_batch(logs[:half], buffer, starts[:half], [len(d) for d in datas[:half]], decode)
    columns.add_batch(logs[half:], buffer, starts[half:], [len(d) for d in datas[half:]],
                      lambda k: decode(k + half))
    assert sorted(decoded) == [k for k in range(600) if k % 17 == 0]   # only the big-endian ones
    arrays = columns.finish({'roll': 'tilt'})
    first_seen = []
    for msg in expected:
        for name in msg.name:
            if name not in first_seen:
                first_seen.append(name)
    assert arrays.names == tuple('tilt' if n == 'roll' else n for n in first_seen)
    np.testing.assert_array_equal(arrays.log_time_ns, logs)
    assert arrays.stamp_ns.tolist() == [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in expected]
    for field, attr in ((arrays.position, 'position'), (arrays.velocity, 'velocity'), (arrays.effort, 'effort')):
        for name, column in field.items():
            recorded = 'roll' if name == 'tilt' else name
            want = []
            for msg in expected:
                values = getattr(msg, attr)
                slot = list(msg.name).index(recorded) if recorded in msg.name else len(values)
                want.append(values[slot] if slot < len(values) else np.nan)   # the first of a repeated name
            np.testing.assert_array_equal(column, want, err_msg=f'{attr} {name}')   # bit for bit, NaN included
    mismatched = columns.mismatched(1)
    assert mismatched.tolist() == [len(m.velocity) != len(m.name) for m in expected]


def test_temperature_rows_decode_a_batch_like_the_type_store():
    store = default_typestore()
    rng = np.random.default_rng(9)
    datas, expected = [], []
    for i in range(200):
        stamp, value = random_stamp(rng), float(rng.normal() * 50)
        msg = make_temperature(stamp, value, frame_id=str(rng.choice(FRAMES)))
        datas.append(bytes(store.serialize_cdr(msg, TEMPERATURE_TYPE, little_endian=bool(i % 13))))
        expected.append((stamp, value, bool(i % 13)))
    datas.append(b'\x00\x01\x00\x00\x01')  # not a message
    expected.append((0, 0.0, False))
    starts = np.cumsum([0] + [len(d) for d in datas[:-1]])
    rows = temperature_rows(b''.join(datas), starts, [len(d) for d in datas])
    assert rows.others.tolist() == [k for k, e in enumerate(expected) if not e[2]]
    assert rows.decoded.tolist() == [k for k, e in enumerate(expected) if e[2]]
    assert rows.stamp_ns.tolist() == [expected[k][0] for k in rows.decoded.tolist()]
    assert rows.temperature_c.tolist() == [expected[k][1] for k in rows.decoded.tolist()]
