"""Parameters at run time (``ros2 param set``): every parameter of every node with a wrong type or an impossible
value is refused with a reason naming it, and the old value stays AND stays in effect (observed on the output, not
only read back); a possible value is applied whole (the model tables included) or not at all.

The nodes run in this process (``in_process``): ``set_parameters`` goes through the same on-set/post-set callbacks
the parameter service calls; outputs are observed by calling the subscription callbacks. A live service round trip
is in test_nodes_live.py.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest
from builtin_interfaces.msg import Time
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, Temperature

from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
from gimbal_friction.estimation.estimator import EstimatorSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.params import AxisParams, parameter_specs

pytestmark = pytest.mark.ros  # real rclpy nodes and contexts on an isolated domain
V = 0.0349
SPECS = {s['name']: s for s in parameter_specs()}


def wrong_values(default: Any, bound: Any = None, choices: Any = None) -> list[Any]:
    """Values of a wrong type, non-finite, or outside the physical bound, for a parameter with this default."""
    if isinstance(default, bool):
        return ['true', 1, 0.0, [True]]
    if isinstance(default, str):
        return [5, 1.5, True, ['a'], 'no_such_choice' if choices or default in ('measured', 'steady_state',
                                                                               'fallback_temperature') else None]
    out: list[Any] = ['abc', True, [1.0], math.nan, math.inf, -math.inf]
    if isinstance(default, int):
        out.append(float(default) + 0.5)
    if bound is not None and bound.high is not None:
        out.append(type(default)(bound.high * 10 + 1))
    if bound is not None and bound.low is not None:
        out.append(type(default)(bound.low - 1 if bound.low_inclusive else bound.low))
    return out


def temperature(t_c: float, sec: int) -> Temperature:
    msg = Temperature(temperature=float(t_c))
    msg.header.stamp = Time(sec=sec)
    return msg


def joint_state(v: float, sec: int, names: tuple[str, ...] = ('elevation',)) -> JointState:
    msg = JointState(name=list(names), position=[0.0] * len(names), velocity=[v] * len(names))
    msg.header.stamp = Time(sec=sec)
    return msg


class FeedforwardProbe:
    """The feedforward node and its output for a fixed input (joint state at 1/3 rpm, -40 degC)."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self.sec = 100

    def torques(self) -> list[float]:
        self.sec += 1
        self.node.on_temperature(temperature(-40.0, self.sec))
        self.node.on_joint_state(joint_state(V, self.sec))
        self.node.on_joint_state(joint_state(-V, self.sec))
        self.node.on_joint_state(joint_state(3.0, self.sec))     # beyond the clamp
        return [m.effort[0] for m in self.node.pub_ff.messages[-3:]]


@pytest.fixture(scope='module')
def ff(in_process: Any) -> FeedforwardProbe:
    from gimbal_friction.nodes.feedforward import FrictionFeedforward
    return FeedforwardProbe(in_process.make(FrictionFeedforward, temperature_timeout_s=30.0))


@pytest.fixture(scope='module')
def estimator(in_process: Any) -> Any:
    from gimbal_friction.nodes.estimator import FrictionEstimator
    return in_process.make(FrictionEstimator)


@pytest.fixture(scope='module')
def logger(in_process: Any, tmp_path_factory: pytest.TempPathFactory) -> Any:
    from gimbal_friction.nodes.residual_logger import ResidualLogger
    return in_process.make(ResidualLogger, output_dir=str(tmp_path_factory.mktemp('log')))


def parameters_of(node_kind: str) -> list[tuple[str, Any, Any, Any]]:
    """(name, default, bound, choices) of every parameter the node declares."""
    out = []
    if node_kind != 'logger':
        for spec in SPECS.values():
            out.append((f'model.{spec["name"]}', spec['default'], spec['bound'], spec['choices']))
            out.append((f'axis.elevation.{spec["name"]}', spec['default'], spec['bound'], spec['choices']))
    classes = {'ff': (FeedforwardSettings, FeedforwardNodeSettings),
               'estimator': (EstimatorSettings, EstimatorNodeSettings), 'logger': (LoggerSettings,)}[node_kind]
    for cls in classes:
        for f in dataclasses.fields(cls):
            out.append((f.name, f.default, None, None))
    return out


def refused_and_unchanged(node: Any, name: str, value: Any, state: Any, observe: Any = None) -> str | None:
    """Set ``name`` to ``value``; a problem description if it was not refused with a reason naming it, or if the
    parameter, the node's effective state or its output changed."""
    before_value = node.get_parameter(name).value
    before_out = observe() if observe else None
    result = node.set_parameters([Parameter(name, value=value)])[0]
    if result.successful:
        node.set_parameters([Parameter(name, value=before_value)])
        return f'{name} = {value!r} accepted'
    if name not in result.reason and 'read-only' not in result.reason:
        return f'{name} = {value!r}: reason does not name it: {result.reason}'
    after = node.get_parameter(name).value
    if not (after == before_value or (isinstance(after, float) and math.isnan(after) and math.isnan(before_value))):
        return f'{name} = {value!r}: read back {after!r}'
    if state() is not None and state() != state.before:
        return f'{name} = {value!r}: effective state changed'
    if observe and observe() != before_out:
        return f'{name} = {value!r}: output changed'
    return None


class State:
    def __init__(self, fn: Any) -> None:
        self.fn = fn
        self.before = fn()

    def __call__(self) -> Any:
        return self.fn()


def test_feedforward_refuses_every_wrong_value_and_keeps_the_old_one_in_effect(ff):
    node = ff.node
    baseline = ff.torques()
    assert baseline[0] == pytest.approx(3.143e-3, rel=2e-3) and baseline[1] == -baseline[0]
    state = State(lambda: (node.ff.settings, dict(node.ff.axes), node.settings))
    problems = []
    for name, default, bound, choices in parameters_of('ff'):
        for value in wrong_values(default, bound, choices):
            if value is None:
                continue
            problem = refused_and_unchanged(node, name, value, state, ff.torques)
            if problem:
                problems.append(problem)
    assert not problems, '\n'.join(problems[:15])
    assert ff.torques() == baseline
    assert not getattr(node, 'callback_errors', {})   # every refusal came from a rule, none from a crash


@pytest.mark.parametrize(('name', 'value', 'needle'), [
    ('model.walther_a', 1.0, 'viscosity'),                 # negative viscosity at every temperature
    ('model.viscosity_offset_cst', 50.0, 'viscosity'),      # negative above 30 degC
    ('model.viscosity_model', 'walther', 'viscosity'),      # Eq. 20 with the Eq. 21 constants
    ('model.walther_b', -1e-9, 'viscosity'),                # overflows
    ('temperature_min_c', -199.0, 'accepted'),              # credible; the table keeps to the validity range
    ('temperature_max_c', 400.0, 'viscosity'),              # the viscosity stays positive: accepted
    ('max_torque_nm', 1e300, 'must lie in'),
    ('table_step_c', 1e-6, 'must lie in'),
])
def test_model_breaking_values_are_refused_whole(ff, name, value, needle):
    """The whole new feedforward (tables included) is built before the change is accepted: a value that breaks
    the model is refused and nothing of it is applied (temperature_min_c was once half-applied)."""
    node = ff.node
    before = ff.torques()
    settings_before, axes_before = node.ff.settings, dict(node.ff.axes)
    result = node.set_parameters([Parameter(name, value=value)])[0]
    if result.successful:   # a value that builds must be in effect, whole
        assert name in ('temperature_min_c', 'temperature_max_c') and getattr(node.ff.settings, name) == value
        assert node.ff.model_ranges == dict.fromkeys(node.ff.axes, (-40.0, 60.0))   # never past the validity range
        assert node.set_parameters([Parameter(name, value=getattr(FeedforwardSettings(), name))])[0].successful
        return
    assert name in result.reason and needle in result.reason, result.reason
    assert node.ff.settings == settings_before and node.ff.axes == axes_before
    assert ff.torques() == before
    # a -150 degC reading is still refused (the credible range did not move)
    node.on_temperature(temperature(-150.0, ff.sec))
    assert node.ff.last_temperature_c == -40.0


def test_a_possible_change_is_in_effect_at_once(ff):
    node = ff.node
    before = ff.torques()
    assert node.set_parameters([Parameter('model.palmgren_factor', value=3.0)])[0].successful
    changed = ff.torques()
    assert changed[0] > before[0]
    assert node.set_parameters([Parameter('max_torque_nm', value=0.001)])[0].successful
    assert ff.torques()[2] == 0.001
    assert node.set_parameters([Parameter('temperature_min_c', value=-50.0)])[0].successful
    node.on_temperature(temperature(-55.0, ff.sec + 1))
    assert node.ff.last_temperature_c != -55.0      # the new credible range is in effect
    for name, value in (('model.palmgren_factor', 1.917), ('max_torque_nm', 0.02), ('temperature_min_c', -60.0)):
        assert node.set_parameters([Parameter(name, value=value)])[0].successful
    assert ff.torques() == before


def test_estimator_refuses_every_wrong_value_and_keeps_the_old_one_in_effect(estimator):
    node = estimator
    state = State(lambda: (node.logic.settings, dict(node.logic.axes), node.settings))
    problems = []
    for name, default, bound, choices in parameters_of('estimator'):
        for value in wrong_values(default, bound, choices):
            if value is None:
                continue
            problem = refused_and_unchanged(node, name, value, state)
            if problem:
                problems.append(problem)
    for name, value in (('model.walther_a', 1.0), ('model.viscosity_offset_cst', 50.0), ('temperature_min_c', -201.0),
                        ('temperature_max_c', 999.0), ('commanded_speed_rad_s', -0.0349), ('method', 'magic')):
        problem = refused_and_unchanged(node, name, value, state)
        if problem:
            problems.append(problem)
    assert not problems, '\n'.join(problems[:15])
    assert not getattr(node, 'callback_errors', {})


def test_logger_refuses_every_wrong_value(logger):
    state = State(lambda: logger.settings)
    problems = []
    for name, default, _, _ in parameters_of('logger'):
        for value in wrong_values(default):
            if value is None:
                continue
            problem = refused_and_unchanged(logger, name, value, state)
            if problem:
                problems.append(problem)
    assert not problems, '\n'.join(problems[:15])
    assert not getattr(logger, 'callback_errors', {})
    # start-up-only settings are refused at run time, with the reason
    result = logger.set_parameters([Parameter('output_dir', value='/tmp/elsewhere')])[0]
    assert not result.successful and 'output_dir' in result.reason and 'start-up' in result.reason


@pytest.mark.slow
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_value_is_either_applied_whole_or_refused_with_nothing_changed(ff, data):
    """Random parameter, random value (any type, any float): afterwards the output is finite and within the clamp,
    and it equals either the old output (refused) or the output of a node started with the new value."""
    node = ff.node
    name, default, _, choices = data.draw(st.sampled_from(parameters_of('ff')))
    value = data.draw(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
                                st.text(max_size=5), st.booleans(), st.sampled_from(list(choices or ['x'])),
                                st.just(default)))
    old = node.get_parameter(name).value
    before = ff.torques()
    result = node.set_parameters([Parameter(name, value=value)])[0]
    after = ff.torques()
    assert all(math.isfinite(x) and abs(x) <= node.ff.settings.max_torque_nm for x in after)
    if not result.successful:
        assert name in result.reason
        assert after == before
    else:
        # the value is in effect: the effective model/settings carry it
        field = name.split('.')[-1]
        if name.startswith(('model.', 'axis.')):
            assert getattr(node.ff.axes['elevation'], field) == pytest.approx(
                AxisParams.from_mapping({field: value}).to_mapping()[field]) or name.startswith('model.')
        elif hasattr(node.ff.settings, field):
            assert getattr(node.ff.settings, field) == value
        else:
            assert getattr(node.settings, field) == value
        restore = old if old is not None else AxisParams().to_mapping()[name.split('.')[-1]]
        assert node.set_parameters([Parameter(name, value=restore)])[0].successful
    assert ff.torques() == before


def test_unsetting_a_parameter_is_refused_not_undeclared(ff):
    """A NOT_SET value would make rclpy undeclare the parameter, and every later read of it would raise."""
    node = ff.node
    for name in ('model.shaft_length_mm', 'axis.elevation.shaft_length_mm', 'max_torque_nm'):
        result = node.set_parameters([Parameter(name, Parameter.Type.NOT_SET)])[0]
        assert not result.successful and name in result.reason and 'cannot be unset' in result.reason
        assert node.has_parameter(name)
    assert node.set_parameters([Parameter('model.palmgren_factor', value=1.917)])[0].successful
    assert not getattr(node, 'callback_errors', {})


@pytest.mark.parametrize('kind', ['ff', 'estimator', 'logger'])
def test_an_undeclared_parameter_is_refused_naming_it(request, kind):
    """The parameter services call set_parameters_atomically: rclpy's own refusal read "Invalid access to undeclared
    parameter(s): []"; the reason names the parameter, the closest declared one and how to list them."""
    fixture = request.getfixturevalue(kind)
    node = getattr(fixture, 'node', fixture)
    name = 'diagnostics_period' if kind == 'logger' else 'model.bal_count'
    result = node.set_parameters_atomically([Parameter(name, value=16)])
    assert not result.successful and repr(name) in result.reason and '[]' not in result.reason
    assert 'did you mean' in result.reason and f'ros2 param list /{node.get_name()}' in result.reason
    assert not node.has_parameter(name)
    # a declared one still goes through the usual checks
    assert node.set_parameters_atomically([Parameter('diagnostics_period_s', value=1.0)]).successful
