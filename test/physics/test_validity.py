"""The model's validity range (issue 31 item 3): every entry point refuses or clamps a temperature outside it and
says so: the in-process model (gimbal_friction.core), the feedforward object the node, the replay and a controller
run (gimbal_friction.feedforward.rule / gimbal_friction.controller)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError, ModelDomainError
from gimbal_friction.core import AxisParams, friction_torque, validity_range, viscosity_cst
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics import model as raw
from gimbal_friction.physics.thermal import axial_squeeze
from gimbal_friction.physics.validity import VALID_T_MAX_C, VALID_T_MIN_C
from gimbal_friction.streams.arrays import ChamberArrays, JointStateArrays, TemperatureArrays

V = 0.0349066   # 1/3 rpm [rad/s]


def test_the_range_is_where_the_paper_computed_and_measured_the_friction():
    r = validity_range(AxisParams())
    assert (r.low_c, r.high_c, r.note) == (VALID_T_MIN_C, VALID_T_MAX_C, '') == (-40.0, 60.0, '')
    assert float(axial_squeeze(AxisParams(), np.linspace(-40.0, 60.0, 101)).min()) > 0.0   # preloaded throughout


def test_the_range_narrows_where_the_bearing_pair_loses_its_preload():
    """Without a gasket the pair gaps above 20 degC (the squeeze of Eq. 16 turns negative: the paper's F_a < 0)."""
    p = AxisParams(gasket_thickness_mm=0.0)
    r = validity_range(p)
    assert (r.low_c, r.high_c) == (-40.0, 20.0) and 'no axial preload' in r.note
    t = np.linspace(r.low_c, r.high_c, 50)
    assert float(axial_squeeze(p, t).min()) >= -1e-9 and float(axial_squeeze(p, 25.0)) < 0.0
    with pytest.raises(ModelDomainError, match='no axial preload anywhere'):
        # assembled at 100 degC without a gasket and with a clearance fit: colder, the aluminium pulls away
        validity_range(AxisParams(reference_temperature_c=100.0, gasket_thickness_mm=0.0, interference_mm=-0.05))
    with pytest.raises(ModelDomainError, match='no axial preload anywhere'):
        Feedforward({'elevation': AxisParams(reference_temperature_c=100.0, gasket_thickness_mm=0.0,
                                             interference_mm=-0.05)}, FeedforwardSettings())


@pytest.mark.parametrize('t', [-100.0, 200.0, -40.5, 60.5, [20.0, 70.0]])
def test_the_in_process_model_refuses_a_temperature_outside_in_one_line(t):
    with pytest.raises(ModelDomainError) as info:
        friction_torque(AxisParams(), t)
    message = str(info.value)
    assert "outside the model's validity range -40..60 degC" in message and '\n' not in message


def test_the_equations_themselves_still_evaluate_past_the_range_when_asked():
    at = float(friction_torque(AxisParams(), -60.0, extrapolate=True).m_total_nmm)
    assert at == float(raw.friction_torque(AxisParams(), -60.0).m_total_nmm) > 40.0
    assert float(friction_torque(AxisParams(), [-40.0]).m_total_nmm[0]) == pytest.approx(3.143, abs=1e-3)


def test_the_viscosity_fit_is_used_over_its_data_and_the_papers_extrapolation():
    assert float(viscosity_cst(AxisParams(), 204.0)) == pytest.approx(1.094, rel=1e-3)   # Table 2, Eq. 21
    for t in (-41.0, 205.0):
        with pytest.raises(ModelDomainError, match=r"viscosity fit's range -40\.\.204 degC"):
            viscosity_cst(AxisParams(), t)


def test_the_feedforward_table_spans_the_credible_range_within_the_validity_range():
    ff = Feedforward({'elevation': AxisParams()}, FeedforwardSettings())   # credible -60..120 degC (the defaults)
    assert ff.model_ranges == {'elevation': (-40.0, 60.0)}
    table = ff.tables['elevation']
    assert (table.t_min, table.t_max) == (-40.0, 60.0)
    narrow = Feedforward({'elevation': AxisParams()}, FeedforwardSettings(temperature_min_c=-30.0,
                                                                          temperature_max_c=50.0))
    assert narrow.model_ranges == {'elevation': (-30.0, 50.0)}
    loose = Feedforward({'elevation': AxisParams(gasket_thickness_mm=0.0)}, FeedforwardSettings())
    assert loose.model_ranges == {'elevation': (-40.0, 20.0)}
    with pytest.raises(ConfigError, match="leaves nothing of the model's validity range"):
        Feedforward({'elevation': AxisParams()}, FeedforwardSettings(temperature_min_c=70.0, temperature_max_c=120.0,
                                                                     fallback_temperature_c=80.0))


def test_a_credible_temperature_outside_is_used_at_the_edge_and_counted():
    ff = Feedforward({'elevation': AxisParams()}, FeedforwardSettings())
    ff.update_temperature(-40.0, time_s=0.0)
    at_edge = ff.torque_nm('elevation', V, time_s=0.1)
    assert ff.counters.temperature_clamped == {}
    assert ff.update_temperature(-55.0, time_s=1.0) is None           # credible: accepted ...
    assert ff.torque_nm('elevation', V, time_s=1.1) == at_edge        # ... used at -40 degC, never extrapolated
    assert ff.update_temperature(95.0, time_s=2.0) is None
    ff.update_temperature(60.0, time_s=3.0)
    hot = ff.torque_nm('elevation', V, time_s=3.1)
    ff.update_temperature(95.0, time_s=4.0)
    assert ff.torque_nm('elevation', V, time_s=4.1) == hot
    assert ff.counters.temperature_clamped == {'elevation': 3}        # ... and counted
    assert ff.update_temperature(-150.0, time_s=5.0) is not None      # beyond the credible range: refused as before
    assert ff.counters.temperature_clamped == {'elevation': 3}
    # the model beyond the range would have been far larger (what the feedforward of today's main gave)
    assert float(raw.friction_torque(AxisParams(), -55.0).m_total_nmm) * 1e-3 > 5 * at_edge


def test_a_bag_counts_the_same_temperatures_as_the_messages():
    """The offline replay's rule (Feedforward.bag_torques) clamps and counts like the node's per-message rule."""
    temps = [-55.0, -20.0, 70.0, 20.0]
    t_ns = np.array([1, 3, 5, 7], dtype=np.int64) * 10**9
    temperature = TemperatureArrays(t_ns, t_ns, np.asarray(temps))
    js_ns = t_ns + 10**8
    joints = JointStateArrays(js_ns, js_ns, ('elevation',), {'elevation': np.zeros(4)},
                              {'elevation': np.full(4, V)}, {'elevation': np.zeros(4)})
    bag = Feedforward({'elevation': AxisParams()}, FeedforwardSettings())
    out = bag.bag_torques(ChamberArrays(temperature, joints, joints))
    live = Feedforward({'elevation': AxisParams()}, FeedforwardSettings())
    torques = []
    for k, t in enumerate(temps):
        live.update_temperature(t, time_s=float(t_ns[k]) * 1e-9)
        torques.append(live.torque_nm('elevation', V, time_s=float(js_ns[k]) * 1e-9))
    assert bag.counters.temperature_clamped == live.counters.temperature_clamped == {'elevation': 2}
    np.testing.assert_array_equal(out.commands_nm[:, 0], torques)
    assert math.isclose(torques[0], live.torque_at('elevation', V, -40.0))


def test_the_in_process_controller_inherits_the_range():
    from gimbal_friction.controller import load_feedforward
    ff = load_feedforward()
    assert ff.model_ranges == {'elevation': (-40.0, 60.0)}
    ff.update_temperature(-48.0, time_s=0.0)
    assert ff.torque_nm('elevation', V, time_s=0.01) == ff.torque_at('elevation', V, -40.0)
    assert ff.counters.temperature_clamped == {'elevation': 1}
