"""``gimbal-friction replay``: summary, residual log, same numbers as the nodes' per-message code, refusals."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from gimbal_friction.chamber.replay import node_settings, replay_bag
from gimbal_friction.cli.main import main
from gimbal_friction.config.loader import axis_params, load_parameters
from gimbal_friction.estimation.estimator import EstimatorLogic
from gimbal_friction.feedforward.rule import Feedforward
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import default_typestore, open_chamber_bag
from gimbal_friction.recording.bag_write import make_joint_state, make_temperature, write_chamber_bag
from gimbal_friction.recording.errors import EmptyInputError
from gimbal_friction.recording.residual_read import read_residual_rows

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / 'bags' / 'chamber_sample'
TRUTH = ROOT / 'bags' / 'chamber_sample.truth.yaml'


@pytest.fixture(scope='module')
def sample_replay(tmp_path_factory):
    out = tmp_path_factory.mktemp('replay')
    assert main(['replay', str(SAMPLE), '--out', str(out), '--format', 'json']) == 0
    return out


def test_summary_per_plateau_and_direction(sample_replay):
    summary = json.loads((sample_replay / 'summary.json').read_text())
    fields = {'temperature_c', 'direction', 'measured_mean_nmm', 'predicted_nmm', 'residual_nmm', 'samples'}
    assert all(fields <= set(r) for r in summary)
    plateaus = sorted({round(r['temperature_c'] / 20) * 20 for r in summary})
    assert plateaus == [-40, -20, 0, 20, 40, 60]
    assert len(summary) == 12 and {r['direction'] for r in summary} == {'cw', 'ccw'}
    truth = axis_params(load_parameters([TRUTH], include_defaults=True), 'elevation')
    for r in summary:
        sign = 1 if r['direction'] == 'cw' else -1
        assert np.sign(r['measured_mean_nmm']) == sign and np.sign(r['predicted_nmm']) == sign
        assert r['residual_nmm'] == pytest.approx(r['measured_mean_nmm'] - r['predicted_nmm'])
        assert r['samples'] >= 100
        if r['direction'] == 'cw':  # CW carries no asymmetry in the synthetic truth
            expected = float(friction_torque(truth, r['temperature_c']).m_total_nmm)
            assert r['measured_mean_nmm'] == pytest.approx(expected, rel=0.03)
    cold = {r['direction']: r['measured_mean_nmm'] for r in summary if r['temperature_c'] < -30}
    assert abs(cold['ccw']) / cold['cw'] == pytest.approx(0.77, abs=0.05)  # the paper's 2.45/3.19


def test_residual_log_is_a_readable_rosbag2_folder(sample_replay):
    folder = sample_replay / 'residuals'
    d, log = read_residual_rows([folder])
    assert len(d) > 20000 and not log.truncated_files
    for topic in (topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT, topics.FEEDFORWARD,
                  topics.MEASURED, topics.MEASURED_DETAIL, topics.RESIDUAL, topics.RESIDUAL_DETAIL):
        assert log.topic_counts.get(topic, 0) > 0, topic
    np.testing.assert_allclose(d.residual_nm, d.measured_nm - d.predicted_nm, rtol=0, atol=1e-15)
    with AnyReader([folder], default_typestore=default_typestore()) as reader:
        assert {c.topic for c in reader.connections} >= {topics.RESIDUAL, topics.RESIDUAL_DETAIL}


@pytest.mark.slow
def test_replay_numbers_equal_the_nodes_message_by_message():
    """The replay runs the nodes' objects on the whole bag; fed message by message, as the nodes are, they give
    the same feedforward, measurements and residual rows."""
    axes, ff_settings, est_settings = node_settings([])
    arrays = open_chamber_bag(SAMPLE).read_arrays()
    res = replay_bag(SAMPLE, None, config_paths=[])
    node_ff = Feedforward(axes, ff_settings)
    node_est = EstimatorLogic(axes, est_settings)
    temp, js, cur = arrays.temperature, arrays.joint_states, arrays.motor_current
    events = sorted([(int(t), 0, i) for i, t in enumerate(temp.log_time_ns)]
                    + [(int(t), 1, i) for i, t in enumerate(js.log_time_ns)]
                    + [(int(t), 2, i) for i, t in enumerate(cur.log_time_ns)])
    torques, measured = [], []
    for log_ns, kind, i in events[:20000]:
        if kind == 0:
            stamp = int(temp.stamp_ns[i]) or log_ns
            node_ff.update_temperature(float(temp.temperature_c[i]), stamp / 1e9)
            measured += node_est.on_temperature(float(temp.temperature_c[i]), int(temp.stamp_ns[i]), log_ns)
        elif kind == 1:
            stamp = int(js.stamp_ns[i])
            p, v = float(js.position['elevation'][i]), float(js.velocity['elevation'][i])
            torques.append(node_ff.message(['elevation'], [v], (stamp or log_ns) / 1e9).torques_nm[0])
            measured += node_est.on_joint_state(stamp, ['elevation'], [p], [v], log_ns)
        else:
            measured += node_est.on_current(int(cur.stamp_ns[i]), ['elevation'], [float(cur.effort['elevation'][i])],
                                            log_ns)
    np.testing.assert_allclose(res.feedforward.commands_nm[:len(torques), 0], torques, rtol=1e-12,
                               atol=1e-18)
    offline = res.measurements.records()[:len(measured)]
    assert len(measured) > 5000
    assert [m.stamp_ns for m in offline] == [m.stamp_ns for m in measured]
    np.testing.assert_array_equal([m.friction_nm for m in offline], [m.friction_nm for m in measured])
    np.testing.assert_array_equal([m.temperature_c for m in offline], [m.temperature_c for m in measured])
    # the residual rows: the measurement next to the feedforward of its joint state
    rows = res.rows
    assert np.array_equal(rows.measured_nm, res.measurements.friction_nm)
    k = np.searchsorted(res.feedforward.stamp_ns, res.measurements.stamp_ns)
    np.testing.assert_array_equal(rows.predicted_nm, res.feedforward.commands_nm[k, 0])
    np.testing.assert_allclose(rows.residual_nm, rows.measured_nm - rows.predicted_nm, rtol=0, atol=0)
    assert np.array_equal(rows.current_a, res.measurements.current_a)    # as measured, not reconstructed


def _tiny_bag(path: Path, *, joint_type: str = topics.JOINT_STATE_TYPE, drop: str | None = None,
              storage: str = 'mcap', rename: dict[str, str] | None = None) -> Path:
    msgs = []
    for i in range(200):
        t = 1_000_000_000 + i * 20_000_000
        v = 2 * math.pi / 180 * (1 if (i // 100) % 2 == 0 else -1)
        msgs.append((topics.TEMPERATURE, topics.TEMPERATURE_TYPE, t, make_temperature(t, -40.0)))
        msgs.append((topics.JOINT_STATES, topics.JOINT_STATE_TYPE, t,
                     make_joint_state(t, ['elevation'], [0.01 * (i % 50) / 50], [v])))
        msgs.append((topics.MOTOR_CURRENT, topics.JOINT_STATE_TYPE, t + 1,
                     make_joint_state(t, ['elevation'], effort=[0.06 * np.sign(v)])))
    rename = rename or {}
    msgs = [(rename.get(tp, tp), ty, t, m) for tp, ty, t, m in msgs if tp != drop]
    if joint_type != topics.JOINT_STATE_TYPE:
        msgs = [(tp, ty, t, m) if tp != topics.MOTOR_CURRENT else (tp, joint_type, t,
                                                                    make_temperature(t, 1.0)) for tp, ty, t, m in msgs]
    return write_chamber_bag(path, msgs, storage=storage)


@pytest.mark.parametrize(('kwargs', 'needle'), [
    ({'drop': topics.MOTOR_CURRENT}, '/gimbal/motor_current'),
    ({'joint_type': topics.TEMPERATURE_TYPE}, 'sensor_msgs/msg/Temperature'),
])
def test_bag_lacking_a_topic_or_with_a_wrong_type_is_refused(tmp_path, capsys, kwargs, needle):
    bag = _tiny_bag(tmp_path / 'bag', **kwargs)
    assert main(['replay', str(bag), '--out', str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / 'out' / 'residuals').exists()


def test_sqlite3_bag_and_topic_remap(tmp_path, capsys):
    bag = _tiny_bag(tmp_path / 'bag', storage='sqlite3', rename={topics.JOINT_STATES: '/gimbal/joint_states'})
    assert main(['replay', str(bag), '--out', str(tmp_path / 'o1')]) == 1
    assert '/joint_states' in capsys.readouterr().err
    assert main(['replay', str(bag), '--out', str(tmp_path / 'o2'), '--topic', '/joint_states=/gimbal/joint_states',
                 '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['messages_in'] == 600 and doc['feedforward_outputs'] == 200
    assert (tmp_path / 'o2' / 'summary.json').exists()
    # an existing log is never overwritten
    assert main(['replay', str(bag), '--out', str(tmp_path / 'o2'), '--topic',
                 '/joint_states=/gimbal/joint_states']) == 1
    assert 'already holds a log' in capsys.readouterr().err


def test_refit_of_the_replayed_log_moves_viscosity_toward_the_truth(sample_replay, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(sample_replay / 'residuals'), '--out', str(out), '--direction', 'cw',
                 '--fit', 'walther_a,palmgren_factor', '--format', 'json']) == 0
    capsys.readouterr()
    refit = axis_params(load_parameters([out]), 'elevation')
    truth = axis_params(load_parameters([TRUTH]), 'elevation')
    base = axis_params(load_parameters(), 'elevation')
    assert abs(refit.walther_a - truth.walther_a) < 0.2 * abs(base.walther_a - truth.walther_a)
    assert abs(refit.palmgren_factor - truth.palmgren_factor) < 0.3 * abs(base.palmgren_factor - truth.palmgren_factor)


def test_a_recorded_reference_velocity_drives_the_replayed_feedforward_as_live(tmp_path):
    """A bag that also holds /gimbal/reference_velocity (a seeker's full graph) replays with the node's
    velocity_source: auto uses the reference while fresh, measured uses the joint states; the residual log holds
    the nodes' topics only."""
    msgs = []
    for i in range(200):
        t = 1_000_000_000 + i * 20_000_000
        v = 2 * math.pi / 180
        msgs.append((topics.TEMPERATURE, topics.TEMPERATURE_TYPE, t, make_temperature(t, -40.0)))
        msgs.append((topics.JOINT_STATES, topics.JOINT_STATE_TYPE, t, make_joint_state(t, ['elevation'], [0.0], [v])))
        msgs.append((topics.MOTOR_CURRENT, topics.JOINT_STATE_TYPE, t + 1,
                     make_joint_state(t, ['elevation'], effort=[0.06])))
        if i < 100:   # the controller's reference: the other way; it stops half way (then stale after 0.5 s)
            msgs.append((topics.REFERENCE_VELOCITY, topics.JOINT_STATE_TYPE, t - 1,
                         make_joint_state(t, ['elevation'], velocity=[-v])))
    bag = write_chamber_bag(tmp_path / 'bag', msgs)
    arrays = open_chamber_bag(bag).read_arrays()
    assert arrays.reference_velocity is not None and len(arrays.reference_velocity) == 100
    auto = replay_bag(bag, tmp_path / 'auto', config_paths=[]).feedforward.commands_nm[:, 0]
    late = np.arange(200) * 0.02 > 99 * 0.02 + 0.5          # the reference is stale
    assert np.all(auto[:100] < 0.0) and np.all(auto[late] > 0.0)
    measured_cfg = tmp_path / 'measured.yaml'
    measured_cfg.write_text('/**:\n  ros__parameters:\n    velocity_source: measured\n')
    measured = replay_bag(bag, tmp_path / 'measured', config_paths=[measured_cfg]).feedforward.commands_nm[:, 0]
    assert np.all(measured > 0.0)
    with AnyReader([tmp_path / 'auto' / 'residuals']) as reader:
        assert topics.REFERENCE_VELOCITY not in {c.topic for c in reader.connections}


def test_summary_counts_equal_the_refit_counts_on_every_plateau(sample_replay, tmp_path, capsys):
    """One rule decides which samples belong to a plateau: replay's summary and refit on its log agree."""
    from gimbal_friction.estimation.plateaus import plateau_of
    summary = json.loads((sample_replay / 'summary.json').read_text())
    capsys.readouterr()
    assert main(['refit', str(sample_replay / 'residuals'), '--out', str(tmp_path / 'r.yaml'),
                 '--format', 'json']) == 0
    bins = json.loads(capsys.readouterr().out)['axes']['elevation']['bins']
    refit_counts: dict[tuple[float, str], int] = {}
    for b in bins:  # summed over speed groups
        key = (b['temperature_bin_c'], b['direction'])
        refit_counts[key] = refit_counts.get(key, 0) + b['samples']
    assert len(summary) == 12
    for r in summary:
        key = (float(plateau_of(r['temperature_c'], 5.0)), r['direction'])
        assert r['samples'] == refit_counts[key], key
        assert r['samples'] > 700  # every sample of the bin, not only those of the steady stretch


@pytest.mark.slow
def test_report_compare_shows_the_refit_model_as_refit_does(sample_replay, tmp_path, capsys):
    """Issue 12: report --compare's refit model is refit's own 'model after' at every plateau: the refitted friction
    plus the calibration torque offset refit fitted beside it (written as data into its file), averaged over the
    plateau's samples. Was: the friction alone at the plateau's mean temperature (1.080 against 1.0756 N*mm, CW at
    +60 degC, with an offset of -0.0048 N*mm)."""
    refit = tmp_path / 'refit.yaml'
    capsys.readouterr()
    assert main(['refit', str(sample_replay / 'residuals'), '--out', str(refit), '--format', 'json']) == 0
    axis = json.loads(capsys.readouterr().out)['axes']['elevation']
    assert axis['offset']['estimated']
    assert main(['report', '--residuals', str(sample_replay / 'residuals'), '--compare', str(refit), '--out',
                 str(tmp_path / 'figures'), '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    after = {(b['temperature_bin_c'], b['sign']): b['model_after_nmm'] for b in axis['bins']}
    assert len(doc['fig13']) == 12
    for r in doc['fig13']:
        assert r['compare_nmm'] == pytest.approx(r['sign'] * after[(r['plateau_c'], r['sign'])], abs=1e-4), r
    assert doc['compare']['torque_offset_nmm'] == pytest.approx(axis['offset']['value_nmm'], rel=1e-12)
    # the table's 'refit model' column prints it as refit's table rounds 'model after'
    from gimbal_friction.cli.report_cmd import summary_table
    warm = next(line for line in summary_table(doc['fig13']).splitlines() if ' 59.' in line and ' cw ' in line)
    assert f'{after[(60.0, 1)]:+.3f}' in warm.split()


# ------------------------------------------------------------------------ empty input, missing topics, non-CDR bags


def _one_line_refusal(capsys, command: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'gimbal-friction {command}: error: '), captured.err
    assert 'Traceback' not in captured.err
    return lines[0]


def test_an_axis_absent_from_the_bag_is_refused_and_nothing_is_written(tmp_path, capsys):
    """Was: 0 samples accepted, exit 0, an empty summary and log. Now: exit 1, one line with the joints present, the
    mapping used and the option; no output folder."""
    bag = _tiny_bag(tmp_path / 'bag')   # joint 'elevation'
    axes = tmp_path / 'axes.yaml'
    axes.write_text('/**:\n  ros__parameters:\n    axes: ["pitch"]\n')
    out = tmp_path / 'out'
    assert main(['replay', str(bag), '--out', str(out), '--config', str(axes)]) == 1
    line = _one_line_refusal(capsys, 'replay')
    assert "no configured axis is in /joint_states (axes: 'pitch'; joints recorded: 'elevation'; joint map: none)" \
        in line and '--joint pitch=elevation' in line
    assert not out.exists()
    assert main(['replay', str(bag), '--out', str(out), '--joint', 'elevation=joint_2']) == 1
    line = _one_line_refusal(capsys, 'replay')
    assert "--joint elevation=joint_2: no joint 'joint_2'" in line and "joints recorded: 'elevation'" in line
    assert not out.exists()
    assert main(['replay', str(bag), '--out', str(out), '--config', str(axes), '--joint', 'pitch=elevation',
                 '--format', 'json']) == 0
    assert json.loads(capsys.readouterr().out)['accepted_samples'] > 0


def test_a_replay_that_accepts_no_sample_is_refused_with_the_estimators_reasons(tmp_path, capsys):
    """The axis is there but no sample qualifies (the test ran at another speed): exit 1, the reasons, nothing
    written; the API raises EmptyInputError before writing too."""
    bag = _tiny_bag(tmp_path / 'bag')
    slow = tmp_path / 'slow.yaml'
    slow.write_text('/**:\n  ros__parameters:\n    commanded_speed_rad_s: 0.5\n')
    out = tmp_path / 'out'
    assert main(['replay', str(bag), '--out', str(out), '--config', str(slow)]) == 1
    line = _one_line_refusal(capsys, 'replay')
    assert 'no friction sample was accepted, nothing written' in line and 'speed off command' in line
    assert not out.exists()
    with pytest.raises(EmptyInputError):
        replay_bag(bag, out, config_paths=[slow])
    assert not out.exists()


def test_every_missing_topic_and_the_topic_option_are_named(tmp_path, capsys):
    bag = _tiny_bag(tmp_path / 'bag', rename={topics.JOINT_STATES: '/gimbal/joint_states',
                                              topics.MOTOR_CURRENT: '/drive/current'})
    assert main(['replay', str(bag), '--out', str(tmp_path / 'out')]) == 1
    line = _one_line_refusal(capsys, 'replay')
    assert f'required topics {topics.JOINT_STATES}, {topics.MOTOR_CURRENT} are missing' in line
    assert f'--topic {topics.JOINT_STATES}=/gimbal/joint_states --topic {topics.MOTOR_CURRENT}=/drive/current' in line
    assert not (tmp_path / 'out').exists()
    assert main(['replay', str(bag), '--out', str(tmp_path / 'out'), '--topic',
                 f'{topics.JOINT_STATES}=/gimbal/joint_states', '--topic',
                 f'{topics.MOTOR_CURRENT}=/drive/current']) == 0


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_bag_not_in_cdr_is_unsupported_for_replay_and_for_recover(tmp_path, capsys, storage):
    """Was: replay 'damaged, run recover', recover 'nothing to recover' (the advice looped). Now both say the
    serialization and that it is not supported, and neither writes anything."""
    bag = _tiny_bag(tmp_path / 'bag', storage=storage)
    meta = bag / 'metadata.yaml'
    meta.write_text(meta.read_text().replace('serialization_format: cdr', 'serialization_format: protobuf'))
    assert main(['replay', str(bag), '--out', str(tmp_path / 'out')]) == 1
    line = _one_line_refusal(capsys, 'replay')
    assert "serialized as 'protobuf'" in line and 'not supported' in line and 'recover' in line
    assert 'damaged or cut short' not in line and '--out NEW' not in line
    assert main(['recover', str(bag), '--out', str(tmp_path / 'fixed')]) == 1
    line = _one_line_refusal(capsys, 'recover')
    assert "serialized as 'protobuf'" in line and 'not supported' in line
    assert not (tmp_path / 'out').exists() and not (tmp_path / 'fixed').exists()


def _learned_correction(axes, positions: bool = True):
    """A correction (the guard off) with a speed profile and, with ``positions``, a ripple found at 2 deg. (A copy
    of the one learned once per model and ``positions``: the fit takes about 10 s.)"""
    import copy

    from gimbal_friction.feedforward.correction import model_identity
    key = (repr(model_identity(axes)), positions)
    if key not in _LEARNED:
        _LEARNED[key] = _learn_correction(axes, positions)
    return copy.deepcopy(_LEARNED[key])


_LEARNED: dict = {}


def _learn_correction(axes, positions: bool):
    from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity
    rng = np.random.default_rng(3)
    n = 20_000
    t = rng.uniform(-60.0, 60.0, n)
    v = rng.choice([-1.0, 1.0], n) * rng.uniform(0.01, 0.1, n)
    p = rng.uniform(-0.2, 0.3, n)
    along = 3e-4 * (1.0 + 0.5 * (v > 0) + positions * 0.5 * np.sin(2 * np.pi * p / np.radians(2.0)))
    s = CorrectionSettings(prior_samples=1.0, guard_min_samples=0, guard_z=0.0)
    c, _ = Correction.from_residuals(s, model_identity(axes), {'elevation': (t, v, p, np.where(v > 0, along, -along),
                                                                            np.full(n, 2e-3))})
    return c


@pytest.mark.slow
def test_replay_with_a_correction_equals_the_node_message_by_message_with_reference_positions(tmp_path, capsys):
    """replay --correction adds the learned correction as the node does: its position map at the reference
    position while the reference drives the torque, else at the joint state's; refused with one line if it was
    learned against other parameters."""
    msgs = []
    for i in range(300):
        t = 1_000_000_000 + i * 20_000_000
        v = 2 * math.pi / 180 * (1 if (i // 100) % 2 == 0 else -1)
        msgs.append((topics.TEMPERATURE, topics.TEMPERATURE_TYPE, t, make_temperature(t, -40.0 + i * 0.1)))
        msgs.append((topics.JOINT_STATES, topics.JOINT_STATE_TYPE, t,
                     make_joint_state(t, ['elevation'], [0.0005 * i], [v])))
        msgs.append((topics.MOTOR_CURRENT, topics.JOINT_STATE_TYPE, t + 1,
                     make_joint_state(t, ['elevation'], effort=[0.06 * np.sign(v)])))
        if i < 150:   # the reference, with its own positions, stops half way (then stale)
            msgs.append((topics.REFERENCE_VELOCITY, topics.JOINT_STATE_TYPE, t - 1,
                         make_joint_state(t, ['elevation'], [1.0 - 0.03 * i], [v])))
    bag = write_chamber_bag(tmp_path / 'bag', msgs)
    axes, ff_settings, _ = node_settings([])
    from gimbal_friction.feedforward.correction import save
    c = _learned_correction(axes)
    path = tmp_path / 'unit.correction.yaml'
    save(c, path)
    res = replay_bag(bag, None, config_paths=[], correction_path=path)
    plain = replay_bag(bag, None, config_paths=[])
    assert res.correction == str(path) and plain.correction is None
    node = Feedforward(axes, ff_settings, correction=_learned_correction(axes))
    arrays = open_chamber_bag(bag).read_arrays()
    temp, js, ref = arrays.temperature, arrays.joint_states, arrays.reference_velocity
    events = sorted([(int(t), 0, i) for i, t in enumerate(temp.log_time_ns)]
                    + [(int(t), 1, i) for i, t in enumerate(ref.log_time_ns)]
                    + [(int(t), 2, i) for i, t in enumerate(js.log_time_ns)])
    torques = []
    for _, kind, i in events:
        if kind == 0:
            node.update_temperature(float(temp.temperature_c[i]), int(temp.stamp_ns[i]) / 1e9)
        elif kind == 1:
            node.update_reference(['elevation'], [float(ref.velocity['elevation'][i])], int(ref.stamp_ns[i]) / 1e9,
                                  [float(ref.position['elevation'][i])])
        else:
            torques.append(node.message(['elevation'], [float(js.velocity['elevation'][i])],
                                        int(js.stamp_ns[i]) / 1e9, [float(js.position['elevation'][i])]).torques_nm[0])
    np.testing.assert_allclose(res.feedforward.commands_nm[:, 0], torques, rtol=1e-12, atol=1e-18)
    delta = res.feedforward.commands_nm[:, 0] - plain.feedforward.commands_nm[:, 0]
    assert np.all(np.abs(delta) > 1e-5)   # the correction is there, along the motion
    # the position used: the reference's while fresh (the ripple follows it), the joint state's after
    at = Feedforward(axes, ff_settings, correction=c)
    t_used = res.feedforward.temperature_c
    v_used = np.asarray([-1.0 if (k // 100) % 2 else 1.0 for k in range(300)]) * 2 * math.pi / 180
    p_ref, p_js = 1.0 - 0.03 * np.arange(300), 0.0005 * np.arange(300)
    for k in (10, 120, 149, 200, 299):
        p = p_ref[k] if k < 150 else p_js[k]
        assert res.feedforward.commands_nm[k, 0] == pytest.approx(at.torque_at('elevation', v_used[k], t_used[k], p),
                                                                   rel=1e-12)
    # the command: --correction, the JSON names it; a correction of another model is refused, nothing written
    assert main(['replay', str(bag), '--out', str(tmp_path / 'out'), '--correction', str(path),
                 '--format', 'json']) == 0
    assert json.loads(capsys.readouterr().out)['correction'] == str(path)
    other = tmp_path / 'other.yaml'
    other.write_text('/**:\n  ros__parameters:\n    axis:\n      elevation:\n        palmgren_factor: 3.0\n')
    assert main(['replay', str(bag), '--out', str(tmp_path / 'refused'), '--config', str(other),
                 '--correction', str(path)]) != 0
    err = capsys.readouterr().err.strip()
    assert 'learned against model parameters' in err and '\n' not in err
    assert not (tmp_path / 'refused').exists()


@pytest.mark.slow
def test_replay_takes_the_nodes_correction_file_unless_told_otherwise(tmp_path):
    """replay_correction: --correction first, else friction_feedforward's correction_file (if it exists and
    use_correction is not false): what the live node would load."""
    from gimbal_friction.chamber.replay import replay_correction

    axes, _, _ = node_settings([])
    path = tmp_path / 'unit.correction.yaml'
    from gimbal_friction.feedforward.correction import save
    save(_learned_correction(axes, positions=False), path)
    cfg = tmp_path / 'node.yaml'
    cfg.write_text(f'friction_feedforward:\n  ros__parameters:\n    correction_file: {path}\n')
    c, source = replay_correction(axes, [cfg])
    assert source == str(path) and c is not None and c.summary()['samples'] > 0
    off = tmp_path / 'off.yaml'
    off.write_text('friction_feedforward:\n  ros__parameters:\n    use_correction: false\n')
    assert replay_correction(axes, [cfg, off]) == (None, None)
    missing = tmp_path / 'missing.yaml'
    missing.write_text(f'friction_feedforward:\n  ros__parameters:\n    correction_file: {tmp_path / "none.yaml"}\n')
    assert replay_correction(axes, [missing]) == (None, None)   # nothing learned yet
    assert replay_correction(axes, [missing], path)[1] == str(path)


def test_a_bag_message_that_is_not_plain_cdr_is_refused_before_it_is_copied_in():
    """Issue 31 item 14: replay gives the writer the lengths of the bag's messages and checks their CDR headers
    itself, as arrays (the writer then skips its per-message checks)."""
    import numpy as np

    from gimbal_friction.chamber.replay import _check_cdr_heads
    from gimbal_friction.recording.bag import RawBatch
    from gimbal_friction.recording.errors import RecordingError
    buffer = b'\x00\x01\x00\x00abcd' + b'\x01\x00\x00\x00efgh'
    batch = RawBatch([('/joint_states', 'sensor_msgs/msg/JointState')], np.zeros(2, dtype=np.int64),
                     np.array([1, 2]), buffer, np.array([0, 8]), np.array([8, 8]))
    with pytest.raises(RecordingError, match=r"a /joint_states message is not plain CDR .*b'\\x01\\x00"):
        _check_cdr_heads(batch)
    _check_cdr_heads(batch._replace(start=batch.start[:1], length=batch.length[:1], topic=batch.topic[:1],
                                    log_time=batch.log_time[:1]))
