"""friction_feedforward learning in service, as its own process: learned from accepted measurements, gated,
bounded, frozen, switched off, reset, saved (periodically and at SIGINT), resumed, and a bad file refused."""

from __future__ import annotations

import dataclasses
import math
import signal
from pathlib import Path

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from test_feedforward_node import request  # the node tests' one request (re-sent until answered)

from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, load, model_identity, save
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, METHOD_OBSERVER

FF = '/gimbal/friction/feedforward'
V_TH = FeedforwardSettings().velocity_threshold_rad_s
V_TEST = 2 * math.pi / 180  # 1/3 rpm in rad/s
DETAIL = '/gimbal/friction/measured_detail'
CORRECTION = '/gimbal/friction/correction'
ROOT = Path(__file__).resolve().parents[2]
T_C = -40.0
pytestmark = pytest.mark.ros


def model_nm(t_c: float, v: float) -> float:
    """The pure model's feedforward (direct, not the node's table) [N·m]."""
    return math.tanh(v / V_TH) * float(friction_torque(AxisParams(), t_c, abs(v) * 30 / math.pi).m_total_nmm) * 1e-3


def send_temperature(probe, t_c, sec):
    msg = Temperature(temperature=float(t_c))
    msg.header.stamp = Time(sec=sec)
    probe.pubs['/gimbal/temperature'].publish(msg)


def detail(sec: int, velocity: float, friction_nm: float, temperature_c: float = T_C, fresh: bool = True,
           joint: str = 'elevation') -> Float64MultiArray:
    """A measured_detail message (the estimator's layout, MEASUREMENT_FIELDS) of an accepted observer sample."""
    row = dict.fromkeys(MEASUREMENT_FIELDS, 0.0)
    row.update(stamp_sec=float(sec), velocity_rad_s=velocity, temperature_c=temperature_c,
               temperature_fresh=1.0 if fresh else 0.0, friction_nm=friction_nm, method=float(METHOD_OBSERVER),
               torque_constant_nm_per_a=0.05, inertia_kg_m2=1e-4)
    n = len(MEASUREMENT_FIELDS)
    msg = Float64MultiArray(data=[row[f] for f in MEASUREMENT_FIELDS])
    msg.layout.dim = [MultiArrayDimension(label=joint, size=n, stride=n)]
    return msg


def start(spawn, probe, *extra: str):
    for msg_type, topic in ((JointState, FF), (DiagnosticArray, '/diagnostics'), (DiagnosticArray, CORRECTION)):
        if topic not in probe.received:
            probe.subscribe(msg_type, topic)
    for msg_type, topic in ((Temperature, '/gimbal/temperature'), (JointState, '/joint_states'),
                            (Float64MultiArray, DETAIL)):
        probe.publisher(msg_type, topic)
    node = spawn('friction_feedforward', '--ros-args', '--params-file', 'config/gimbal_friction.yaml',
                 '-p', 'temperature_timeout_s:=30.0', '-p', 'diagnostics_period_s:=0.2',
                 '-p', 'correction_publish_period_s:=0.2', *extra)
    for topic in ('/joint_states', '/gimbal/temperature', DETAIL):
        probe.wait_matched(topic)
    probe.wait_publisher(FF)
    return node


def temperature_in_use(probe, sec: int) -> int:
    """Send T_C stamped ``sec`` until a feedforward uses it; the stamp the samples and requests carry next."""
    expected = model_nm(T_C, V_TEST)
    s = [sec]

    def ok():
        send_temperature(probe, T_C, s[0])
        probe.executor.spin_once(timeout_sec=0.05)
        s[0] += 1
        # -40 degC in use (the 20 degC fallback gives a third of it); a loaded correction may add to it
        return request(probe, ['elevation'], [V_TEST], s[0]).effort[0] > 0.95 * expected

    probe.spin_until(ok, what='temperature in use')
    return s[0] + 1


def learning_status(probe) -> dict[str, str] | None:
    for arr in reversed(probe.received['/diagnostics']):
        for st in arr.status:
            if st.name == 'gimbal_friction/feedforward/learning':
                return {'level': st.level, 'message': st.message, **{kv.key: kv.value for kv in st.values}}
    return None


def cells(probe, after: int = 0) -> dict[str, dict[str, str]] | None:
    """The latest correction message received after index ``after``: cell name -> values."""
    msgs = probe.received[CORRECTION][after:]
    if not msgs:
        return None
    return {st.name: {'level': st.level, 'message': st.message, **{kv.key: kv.value for kv in st.values}}
            for st in msgs[-1].status}


def wait_status(probe, cond, what):
    n = len(probe.received['/diagnostics'])

    def ok():
        st = learning_status(probe) if len(probe.received['/diagnostics']) > n else None
        return st is not None and cond(st)

    probe.spin_until(ok, what=what)
    return learning_status(probe)


def set_param(probe, name, value, ok=True):
    client = probe.node.create_client(SetParameters, '/friction_feedforward/set_parameters')
    probe.spin_until(client.service_is_ready, what='set_parameters service')
    if isinstance(value, bool):
        pv = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
    elif isinstance(value, str):
        pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    else:
        pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(value))
    future = client.call_async(SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)]))
    probe.spin_until(future.done, what=f'set {name}')
    result = future.result().results[0]
    assert result.successful == ok, result.reason
    return result


def get_bool(probe, name):
    client = probe.node.create_client(GetParameters, '/friction_feedforward/get_parameters')
    probe.spin_until(client.service_is_ready, what='get_parameters service')
    future = client.call_async(GetParameters.Request(names=[name]))
    probe.spin_until(future.done, what=f'get {name}')
    return future.result().values[0].bool_value


def send_samples(probe, sec, n, velocity, friction_nm, **kw):
    for k in range(n):
        probe.pubs[DETAIL].publish(detail(sec + k % 3, velocity, friction_nm, **kw))
    probe.executor.spin_once(timeout_sec=0.01)


CELL_CW = 'gimbal_friction/correction/elevation/cw/-40'
CELL_CCW = 'gimbal_friction/correction/elevation/ccw/-40'


@pytest.mark.slow
def test_learns_gates_bounds_freezes_resets_saves_and_resumes(spawn, probe, monkeypatch, tmp_path):
    """A +20 % friction at -40 degC is learned (topic, output), refused samples are counted by reason, a 3x
    friction saturates at the bound, freeze / pure model / reset act at once, and the file is saved periodically and
    at SIGINT and loaded again at start."""
    monkeypatch.chdir(ROOT)
    path = tmp_path / 'correction.yaml'
    # the guard off (every candidate applied at once: the guard's own test is below), a bound of half the model
    params = ('-p', 'learning_enabled:=true', '-p', f'correction_file:={path}', '-p', 'correction_prior_samples:=5.0',
              '-p', 'learning_max_rate_nm_per_min:=1.0', '-p', 'learning_step_period_s:=0.1',
              '-p', 'learning_save_period_s:=0.5', '-p', 'correction_guard_min_samples:=0',
              '-p', 'correction_guard_z:=0.0', '-p', 'correction_max_relative:=0.5')
    node = start(spawn, probe, *params)
    sec = temperature_in_use(probe, 100)
    pure = request(probe, ['elevation'], [V_TEST], sec).effort[0]
    model = model_nm(T_C, V_TEST)          # the model at the sample's speed (tanh(v/v_th) = 1 to 1e-7)
    offset = 0.2 * model
    assert not path.exists()               # nothing learned yet: nothing saved

    # learned: 45 accepted samples with prior 5 -> 45 / 47.5 of the offset (and 45 CCW samples at the model: a cell
    # moves once its temperature bin has samples in both directions; the CCW cell learns 0, so half the CW value is the
    # part along the motion and half the part independent of it, each shrunk like 5 samples: CW gets all of it, CCW
    # none)
    send_samples(probe, sec, 45, V_TEST, model + offset)
    send_samples(probe, sec, 45, -V_TEST, -model)
    probe.spin_until(lambda: (c := cells(probe)) is not None and CELL_CW in c and int(c[CELL_CW]['samples']) == 45
                     and float(c[CELL_CW]['value_nm']) > 0.85 * offset, what='the correction learned')
    value = float(cells(probe)[CELL_CW]['value_nm'])
    assert value == pytest.approx(45 / 47.5 * offset, rel=0.03)
    out = request(probe, ['elevation'], [V_TEST], sec + 1).effort[0]
    assert out == pytest.approx(pure + value, rel=1e-3)   # the feedforward moved towards the measured friction
    # (the CCW samples sit on the model: its cell learned ~0, to the difference of the exact model and the table)
    assert request(probe, ['elevation'], [-V_TEST], sec + 2).effort[0] == pytest.approx(-pure, rel=1e-6)

    # gates: a stale temperature (the node's own rule, and the estimator's flag), near a reversal
    send_samples(probe, sec + 200, 4, V_TEST, model + offset)
    send_samples(probe, sec, 3, V_TEST, model + offset, fresh=False)
    send_samples(probe, sec, 5, 0.001, model + offset)
    st = wait_status(probe, lambda s: s.get('refused: stale temperature') == '7'
                     and s.get('refused: near reversal') == '5', 'refusals counted')
    assert st['samples_used'] == '90' and st['state'] == 'active' and st['message'].startswith('learning active')
    # the refits ran in the default worker, a child process, none timed out or failed
    assert st['fit_worker'] == 'process' and int(st['fits']) > 0 and st['fit_timeouts'] == st['fit_failures'] == '0'

    # periodic save: the file holds what was learned
    probe.spin_until(lambda: path.exists() and load(path).summary()['samples'] == 90, what='periodic save')

    # bound: 3x the model in the other direction saturates: the part along the motion held at max_relative (0.5) x
    # |model|, the part independent of the direction at max_independent_nm (5 mN*m, above that here)
    send_samples(probe, sec, 45, -V_TEST, -3.0 * model)
    st = wait_status(probe, lambda s: s['state'] == 'saturated', 'saturation reported')
    assert st['level'] == b'\x01' and int(st['saturated_cells']) >= 1
    probe.spin_until(lambda: (c := cells(probe)) is not None and CELL_CCW in c
                     and c[CELL_CCW]['state'] == 'saturated', what='saturated cell on the topic')
    floor = CorrectionSettings().floor_nm

    def split(n_cw: int) -> tuple[float, float]:
        """(odd, even) of the bounded target: each direction's level is its sum over n + n0 / 2 (the parts along
        and independent of the motion each shrunk like 5 samples); CW n_cw samples of +offset, CCW 45 of 0 and 45
        of 2 x model along the motion; odd held at 0.5 model + floor, even within max_independent_nm."""
        cw, ccw = n_cw * offset / (n_cw + 2.5), 90 * model / 92.5
        return min(0.5 * (cw + ccw), 0.5 * model + floor), 0.5 * (cw - ccw)

    odd, even = split(45)
    # the applied values move at the learning rate: wait until both cells sit on the bounded target
    probe.spin_until(lambda: float(cells(probe)[CELL_CCW]['value_nm']) == pytest.approx(odd - even, rel=0.02)
                     and float(cells(probe)[CELL_CW]['value_nm']) == pytest.approx(odd + even, abs=0.02 * model),
                     what='the bounded target applied')
    neg = request(probe, ['elevation'], [-V_TEST], sec + 3).effort[0]
    assert neg == pytest.approx(-(model + odd) + even, rel=0.02)   # tau = tanh(v/v_th) (model + odd) + even
    assert -3.0 * model < neg < -model
    out = request(probe, ['elevation'], [V_TEST], sec + 3).effort[0]   # the CW torque now: CW less than learned
    assert out == pytest.approx(pure + odd + even, abs=0.02 * model)    # alone (the CCW cell took the common part)

    # freeze: samples refused, the correction stays
    set_param(probe, 'learning_frozen', True)
    send_samples(probe, sec, 6, V_TEST, model + 5 * offset)
    st = wait_status(probe, lambda s: s.get('refused: frozen') == '6', 'frozen samples refused')
    assert st['state'] == 'frozen'
    assert request(probe, ['elevation'], [V_TEST], sec + 4).effort[0] == pytest.approx(out, rel=1e-9)
    set_param(probe, 'learning_frozen', False)

    # pure model at once, the learned state kept
    set_param(probe, 'use_correction', False)
    assert request(probe, ['elevation'], [V_TEST], sec + 5).effort[0] == pure
    set_param(probe, 'use_correction', True)
    assert request(probe, ['elevation'], [V_TEST], sec + 6).effort[0] == pytest.approx(out, rel=1e-9)

    # saved at SIGINT: 10 more samples after the last periodic save are in the file
    send_samples(probe, sec, 10, V_TEST, model + offset)
    wait_status(probe, lambda s: s['samples_used'] == '145', 'the last samples learned')
    rc, text = node.stop(signal.SIGINT)
    assert rc == 0 and 'Traceback' not in text, text
    assert load(path).summary()['samples'] == 145

    # restart: resumes from the file (the output is corrected before any new sample)
    probe.received[FF].clear()
    node = start(spawn, probe, *params)
    sec = temperature_in_use(probe, 400)
    resumed = request(probe, ['elevation'], [V_TEST], sec).effort[0]
    odd, even = split(55)
    assert resumed == pytest.approx(pure + odd + even, abs=0.02 * model) and resumed > pure + 0.5 * (odd + even)
    st = wait_status(probe, lambda s: s['loaded_from'] == str(path), 'loaded from the file')
    assert st['load_error'] == 'none'

    # reset: empty at once (pure model), the parameter set back, the empty correction saved
    set_param(probe, 'learning_reset', True)
    assert request(probe, ['elevation'], [V_TEST], sec + 1).effort[0] == pure
    probe.spin_until(lambda: not get_bool(probe, 'learning_reset'), what='learning_reset set back')
    n = len(probe.received[CORRECTION])
    probe.spin_until(lambda: (c := cells(probe, n)) is not None and not any('/cw/' in k or '/ccw/' in k for k in c),
                     what='no cells after the reset')
    probe.spin_until(lambda: load(path).summary()['samples'] == 0, what='the reset saved')
    assert node.stop()[0] == 0


@pytest.mark.slow
def test_corrupt_or_mismatched_file_is_refused_and_the_node_runs_on_the_pure_model(spawn, probe, monkeypatch,
                                                                                      tmp_path):
    monkeypatch.chdir(ROOT)
    corrupt = tmp_path / 'corrupt.yaml'
    corrupt.write_text('format: [gimbal_friction/correction\n')
    other = tmp_path / 'other.yaml'
    wrong_model = model_identity({'elevation': dataclasses.replace(AxisParams(), scale_positive=1.1)})
    c = Correction(CorrectionSettings(prior_samples=1.0), wrong_model)
    c.add_residuals('elevation', [T_C] * 20, [V_TEST] * 20, [0.0] * 20, [1e-3] * 20, [3e-3] * 20)
    c.settle(guarded=False)
    save(c, other)
    before = other.read_bytes()
    for path, words in ((corrupt, 'not valid YAML'), (other, 'learned against model parameters')):
        node = start(spawn, probe, '-p', f'correction_file:={path}', '-p', 'learning_enabled:=true',
                     '-p', 'learning_save_period_s:=0.2')
        sec = temperature_in_use(probe, 100)
        assert request(probe, ['elevation'], [V_TEST], sec).effort[0] == pytest.approx(model_nm(T_C, V_TEST),
                                                                                       rel=1e-3)
        probe.pubs[DETAIL].publish(detail(sec, V_TEST, 2 * model_nm(T_C, V_TEST)))   # learned, never saved there
        st = wait_status(probe, lambda s: s['load_error'] != 'none' and s['last_save_error'] != 'none',
                         'the refusal on /diagnostics')
        assert words in st['load_error'] and str(path) in st['load_error'] and st['level'] == b'\x01'
        assert 'not overwritten' in st['last_save_error']
        if path == corrupt:   # at run time a bad file, or another cell layout, is refused as a parameter value
            refused = set_param(probe, 'correction_file', str(other), ok=False)
            assert 'learned against model parameters' in refused.reason and '\n' not in refused.reason
            refused = set_param(probe, 'correction_temperature_bin_c', 2.5, ok=False)
            assert 'correction_temperature_bin_c' in refused.reason and 'cannot change' in refused.reason
        rc, text = node.stop()
        assert rc == 0 and 'Traceback' not in text, text
        refusals = [line for line in text.splitlines() if words in line]
        assert len(refusals) == 1 and 'pure model' in refusals[0], text
        probe.received['/diagnostics'].clear()
    assert other.read_bytes() == before and corrupt.read_text() == 'format: [gimbal_friction/correction\n'


# ------------------------------------------------------------------ the node's keeper of the correction (no ROS)
def _learned(identity, settings=None, n=20):
    c = Correction(settings or CorrectionSettings(prior_samples=1.0), identity)
    c.add_residuals('elevation', [T_C] * n, [V_TEST] * n, [0.0] * n, [1e-3] * n, [3e-3] * n)
    c.settle(guarded=False)
    return c


def test_keeper_loads_saves_only_changes_and_never_overwrites_a_refused_file(tmp_path):
    from gimbal_friction.feedforward.correction import CorrectionKeeper, LearningSettings

    ident = model_identity({'elevation': AxisParams()})
    path = tmp_path / 'c.yaml'
    save(_learned(ident), path)
    k = CorrectionKeeper(ident, CorrectionSettings(prior_samples=10.0), LearningSettings())
    k.start(str(path))
    assert k.load_error is None and k.loaded_from == str(path) and k.load_note is None
    # the file's rows, the parameters' prior (and bound, guard): the candidate follows the parameters
    assert k.correction.settings.prior_samples == 10.0 and k.correction.summary()['samples'] == 20
    fit = k.correction.refit('elevation', search=False)
    # (one direction: along and independent each shrunk like n0 = 10 samples, so n + n0 / 2; octaves tied)
    assert fit.flat_nm[0].max() == pytest.approx(20 * 1e-3 / 25, rel=1e-4)
    assert not k.save(str(path))                       # nothing changed: nothing written
    k.dirty = True
    assert k.save(str(path)) and k.saves == 1 and k.last_save_error is None

    # another cell layout: refused with one line naming the parameter
    other_layout = tmp_path / 'layout.yaml'
    save(_learned(ident, CorrectionSettings(temperature_min_c=-60.0, temperature_max_c=120.0,
                                            temperature_bin_c=10.0)), other_layout)
    k2 = CorrectionKeeper(ident, CorrectionSettings(), LearningSettings())
    k2.start(str(other_layout))
    assert 'correction_temperature_min_c' in k2.load_error and '\n' not in k2.load_error
    assert k2.correction.summary()['samples'] == 0     # the pure model
    k2.dirty = True
    assert not k2.save(str(other_layout)) and 'not overwritten' in k2.last_save_error
    other_layout.unlink()                              # the user deleted it: saved again
    assert k2.save(str(other_layout)) and k2.last_save_error is None

    # a model change empties the correction
    assert k.set_identity(model_identity({'elevation': dataclasses.replace(AxisParams(), scale_positive=0.9)}))
    assert k.correction.summary()['samples'] == 0 and k.dirty


def test_residual_model_is_the_feedforward_rule_without_sign_and_clamp():
    from gimbal_friction.common.xp import SCALAR
    from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
    from gimbal_friction.nodes.feedforward import model_along_nm

    p = dataclasses.replace(AxisParams(), direction_asymmetry_cold=0.2)
    ff = Feedforward({'elevation': p}, FeedforwardSettings())
    v_th = ff.settings.velocity_threshold_rad_s
    for t_c in (-40.0, 12.3, 60.0):
        for v in (0.0349, -0.0349, 0.2):
            along = model_along_nm(ff, 'elevation', v, t_c)
            assert along * v > 0.0
            assert math.tanh(v / v_th) * abs(along) == pytest.approx(ff.rule('elevation', v, t_c, SCALAR), rel=1e-12)


@pytest.mark.slow
def test_a_hostile_correction_file_never_stops_the_node(spawn, probe, monkeypatch, tmp_path):
    """Issue 26: a file that is not UTF-8, one with an infinite bin or an absurd count, a YAML nested 30000 deep and
    a FIFO each leave the node running on the pure model at start-up (one line naming the cause), and are refused
    as a parameter change at run time; the node's feedforward never stops."""
    import os
    monkeypatch.chdir(ROOT)
    good = tmp_path / 'good.yaml'
    save(_learned(model_identity({'elevation': AxisParams()})), good)
    text = good.read_text().rsplit('sha256:', 1)[0]   # (its sha256 line deleted: a deliberate edit, then checked)
    files = {'not utf-8': (tmp_path / 'binary.yaml', 'not UTF-8'),
             'infinite bin': (tmp_path / 'inf.yaml', 'bin'),
             'nested': (tmp_path / 'nested.yaml', 'nested more than'),
             'fifo': (tmp_path / 'fifo.yaml', 'not a regular file')}
    files['not utf-8'][0].write_bytes(b'\xff\xfe')
    files['infinite bin'][0].write_text(text.replace('bin: 4', 'bin: .inf', 1))
    files['nested'][0].write_text('x: ' + '[' * 30000 + ']' * 30000 + '\n')
    os.mkfifo(files['fifo'][0])
    pure = model_nm(T_C, V_TEST)
    for name, (path, words) in files.items():
        node = start(spawn, probe, '-p', f'correction_file:={path}')
        sec = temperature_in_use(probe, 100)
        assert request(probe, ['elevation'], [V_TEST], sec).effort[0] == pytest.approx(pure, rel=1e-3), name
        st = wait_status(probe, lambda s: s['load_error'] != 'none', f'{name}: the refusal on /diagnostics')
        assert words in st['load_error'] and '\n' not in st['load_error'], (name, st['load_error'])
        for other, (bad, other_words) in files.items():   # at run time: refused as a parameter value, one line
            if other != name:
                refused = set_param(probe, 'correction_file', str(bad), ok=False)
                assert other_words in refused.reason and '\n' not in refused.reason, (other, refused.reason)
        assert request(probe, ['elevation'], [V_TEST], sec + 1).effort[0] == pytest.approx(pure, rel=1e-3), name
        rc, out = node.stop()
        assert rc == 0 and 'Traceback' not in out, (name, out)
        probe.received['/diagnostics'].clear()


@pytest.mark.slow
def test_a_fit_worker_that_dies_is_reported_and_the_feedforward_keeps_its_correction(spawn, probe, monkeypatch,
                                                                                      tmp_path):
    """The refits run in a child process of the node; killed, the failure is counted and warned about on
    /diagnostics, the feedforward keeps the correction it had, and a new worker learns on."""
    import os

    monkeypatch.chdir(ROOT)
    node = start(spawn, probe, '-p', 'learning_enabled:=true', '-p', f'learning_output_file:={tmp_path / "c.yaml"}',
                 '-p', 'correction_prior_samples:=5.0', '-p', 'learning_max_rate_nm_per_min:=1.0',
                 '-p', 'learning_step_period_s:=0.1', '-p', 'correction_guard_min_samples:=0',
                 '-p', 'correction_guard_z:=0.0')
    sec = temperature_in_use(probe, 100)
    pure = request(probe, ['elevation'], [V_TEST], sec).effort[0]
    model = model_nm(T_C, V_TEST)
    send_samples(probe, sec, 45, V_TEST, 1.2 * model)
    send_samples(probe, sec, 45, -V_TEST, -model)
    probe.spin_until(lambda: (c := cells(probe)) is not None and CELL_CW in c and int(c[CELL_CW]['samples']) == 45,
                     what='the correction learned')
    st = wait_status(probe, lambda s: s['fit_worker_pid'] != 'none', 'the worker running')
    pid = int(st['fit_worker_pid'])
    assert pid != node.proc.pid and st['fit_failures'] == '0'
    # the fit is reported by the worker; the node swaps it in at its next poll and applies it at its next step
    stamp = [sec]

    def applied() -> float:
        stamp[0] += 1
        return float(request(probe, ['elevation'], [V_TEST], stamp[0]).effort[0])

    probe.spin_until(lambda: applied() > pure * 1.1, what='the learned correction applied')
    learned = applied()

    os.kill(pid, signal.SIGKILL)
    send_samples(probe, sec, 6, V_TEST, 1.2 * model)     # (the next step finds the worker gone)
    st = wait_status(probe, lambda s: s['fit_failures'] == '1', 'the failure reported')
    assert st['level'] == b'\x01' and 'refits 1 new failures' in st['message'] and 'died' in st['last_fit_error']
    assert applied() == learned   # the correction it had
    send_samples(probe, sec, 6, V_TEST, 1.2 * model)
    st = wait_status(probe, lambda s: s['fit_worker_pid'] not in ('none', str(pid)) and int(s['fits']) > 0
                     and s['samples_in_fit'] == '0' and s['fit_failures'] == '1', 'a new worker at work')
