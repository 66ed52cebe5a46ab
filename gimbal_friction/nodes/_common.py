"""Machinery shared by the nodes: model/settings parameters with descriptors, diagnostics, and ``main``.

One job in one module: the nodes' shared ROS machinery (parameter declaration and validation, diagnostics and
``main`` share the declared descriptors).

Model parameters (every :class:`AxisParams` field) are declared as ``model.<field>`` with the packaged defaults,
and per-joint overrides as ``axis.<joint>.<field>`` (unset unless given), exactly the layout of the parameter
files (config.py). Values are validated by the core on start-up and on every ``set_parameters``: an invalid value
is refused with the core's reason and the old value stays.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import math
import os
import re
import signal
import sys
import tempfile
import threading
import weakref
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, TypeVar

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError, ModelDomainError
from gimbal_friction.common.settings import settings_from
from gimbal_friction.common.text import did_you_mean
from gimbal_friction.config.loader import AXES_DESCRIPTION, axis_names, check_parameter_names, load_parameters
from gimbal_friction.config.parameter_rules import SETTINGS_RULES, Rule, model_rule
from gimbal_friction.config.rcl import command_line_parameters
from gimbal_friction.physics.params import AxisParams, parameter_specs
from gimbal_friction.physics.table import FrictionTable
from gimbal_friction.streams import diagnostics
from gimbal_friction.streams.delivery import InputCounter as InputCounter  # noqa: PLC0414 - re-exported (mypy)

T = TypeVar('T')
OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


#: the ends of a descriptor's range where the rule has no bound on that side: the largest finite values (a
#: descriptor range cannot be half-open; the description and additional_constraints say "no bound")
_DOUBLE_END = sys.float_info.max
_INTEGER_END = 2**63 - 1
#: parameter types in words, for a refusal
_TYPE_WORDS = {Parameter.Type.BOOL: 'true or false', Parameter.Type.INTEGER: 'an integer',
               Parameter.Type.DOUBLE: 'a double (a number with a decimal point: 1.0, not 1)',
               Parameter.Type.STRING: 'a string', Parameter.Type.BYTE_ARRAY: 'a byte array',
               Parameter.Type.BOOL_ARRAY: 'a list of booleans', Parameter.Type.INTEGER_ARRAY: 'a list of integers',
               Parameter.Type.DOUBLE_ARRAY: 'a list of doubles (1.0, not 1)',
               Parameter.Type.STRING_ARRAY: 'a list of strings', Parameter.Type.NOT_SET: 'unset'}


#: node -> parameter -> its fixed type, for the parameters declared dynamically typed because they start unset
_EXPECTED_TYPES: weakref.WeakKeyDictionary[Node, dict[str, Parameter.Type]] = weakref.WeakKeyDictionary()


def _whole_int64(value: float) -> bool:
    """A finite whole double that a ROS integer (int64) holds."""
    return math.isfinite(value) and value == int(value) and -2.0**63 <= value < 2.0**63


def ros_type(default: Any) -> Parameter.Type:
    """The fixed ROS parameter type of a parameter with this default (a settings field's: a float default is a
    double even where the packaged file writes it without a decimal point)."""
    if isinstance(default, tuple):
        default = list(default)
    if isinstance(default, list) and default and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                    for v in default):
        return Parameter.Type.DOUBLE_ARRAY if any(isinstance(v, float) for v in default) \
            else Parameter.Type.INTEGER_ARRAY
    return Parameter.Type.from_parameter_value(default)


def typed_value(default: Any, value: Any) -> Any:
    """``value`` as the ROS type of ``default`` where that loses nothing (an integer for a double, a whole double for
    an integer, integers for a list of doubles, a tuple as a list); anything else unchanged (refused by type)."""
    kind = ros_type(default)
    if isinstance(value, tuple):
        value = list(value)
    if kind == Parameter.Type.DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind == Parameter.Type.INTEGER and isinstance(value, float) and _whole_int64(value):
        return int(value)
    if kind == Parameter.Type.DOUBLE_ARRAY and isinstance(value, list) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return [float(v) for v in value]
    return value


def _descriptor(name: str, unit: str, description: str, *, default: Any, rule: Rule | None = None,
                read_only: bool = False) -> ParameterDescriptor:
    """The descriptor of a parameter: its fixed type (that of ``default``), description with the unit and the
    allowed values, and the range of ``rule`` (a side without bound gets the largest finite value)."""
    unit_txt = '' if unit in ('', '-') else f' [{unit}]'
    kind = ros_type(default)
    text = f'{description}{unit_txt}'
    desc = ParameterDescriptor(name=name, type=kind.value, read_only=read_only, dynamic_typing=False)
    if rule is not None:
        allowed = rule.text(unit)
        open_side = not rule.choices and (rule.low is None) != (rule.high is None)
        if kind in (Parameter.Type.INTEGER, Parameter.Type.DOUBLE) and (rule.low is not None
                                                                       or rule.high is not None):
            if kind == Parameter.Type.INTEGER:
                low = -_INTEGER_END if rule.low is None else math.ceil(rule.low)
                high = _INTEGER_END if rule.high is None else math.floor(rule.high)
                desc.integer_range = [IntegerRange(from_value=low, to_value=high, step=1)]
            else:
                desc.floating_point_range = [FloatingPointRange(
                    from_value=-_DOUBLE_END if rule.low is None else float(rule.low),
                    to_value=_DOUBLE_END if rule.high is None else float(rule.high), step=0.0)]
            if open_side:
                allowed += ' (no bound on the other side: the range ends at the largest finite value)'
            elif rule.low_open or rule.high_open:
                allowed += ' (an excluded end of the range is refused)'
        desc.additional_constraints = allowed
        text += f'; allowed: {allowed}'
    desc.description = text
    return desc


def typed_descriptor(name: str, unit: str, description: str, default: Any, rule: Rule | None = None,
                     read_only: bool = False) -> ParameterDescriptor:
    """:func:`_descriptor` for a node module that declares its own parameters (gimbal_sim, chamber_replay)."""
    return _descriptor(name, unit, description, default=default, rule=rule, read_only=read_only)


def _value(param: Parameter[Any]) -> Any:
    if param.type_ == Parameter.Type.NOT_SET:
        return None
    value = param.value
    if isinstance(value, (list, tuple)) or type(value).__name__ == 'array':
        return list(value)
    return value


def declare_axes(node: Node, default: list[str] | None = None) -> list[str]:
    """Declare the read-only ``axes`` parameter (the configured joints; default: the packaged file's) and return
    the validated joint names.

    Raises:
        ConfigError: not a non-empty list of unique joint names.
    """
    if default is None:
        default = axis_names(load_parameters())
    if node.has_parameter('axes'):   # (declared by an earlier configure: read again)
        return axis_names({'axes': _value(node.get_parameter('axes'))})
    try:
        node.declare_parameter('axes', default, _descriptor('axes', '', AXES_DESCRIPTION, default=default,
                                                            read_only=True))
    except Exception as err:  # rclpy's InvalidParameterTypeException: one line naming the parameter
        if type(err).__module__.startswith('rclpy') and 'Parameter' in type(err).__name__:
            raise ConfigError('axes', 'must be a non-empty list of joint names') from None
        raise
    return axis_names({'axes': _value(node.get_parameter('axes'))})


def _model_check(full: str, field: str) -> Callable[[Any], Any]:
    """The validation of model parameter ``field`` alone, its error naming ``full``."""
    def check(value: Any) -> None:
        try:
            AxisParams.from_mapping({field: value})
        except ConfigError as err:
            raise ConfigError(full, err.rule, err.value) from None
    return check


class ModelParameters:
    """Declares the model parameters on ``node`` and turns them into validated :class:`AxisParams`."""

    def __init__(self, node: Node) -> None:
        self.node = node
        defaults = load_parameters()  # packaged config/gimbal_friction.yaml
        default_axes = axis_names(defaults)
        self.axes = declare_axes(node, default_axes)
        model_defaults = {**AxisParams().to_mapping(), **(defaults.get('model') or {})}
        default_overrides = defaults.get('axis') or {}
        self.specs = parameter_specs()
        #: parameter name -> its default (packaged file over AxisParams), for messages
        self.defaults: dict[str, Any] = {f'model.{k}': v for k, v in model_defaults.items()}
        self.defaults.update({f'axis.{a}.{k}': v for a in self.axes
                              for k, v in (default_overrides.get(a) or {}).items()})
        for spec in self.specs:
            name = spec['name']
            declare_typed(node, f'model.{name}', typed_value(spec['default'], model_defaults[name]),
                          _descriptor(f'model.{name}', spec['unit'], spec['description'], default=spec['default'],
                                      rule=model_rule(name)), _model_check(f'model.{name}', name))
        for axis in self.axes:
            for spec in self.specs:
                name = spec['name']
                default = (default_overrides.get(axis) or {}).get(name)
                full = f'axis.{axis}.{name}'
                if node.has_parameter(full):   # (declared by an earlier configure of a lifecycle node)
                    continue
                desc = _descriptor(full, spec['unit'], f'override of model.{name} for joint {axis} (unset unless '
                                   'given)', default=spec['default'], rule=model_rule(name))
                if default is None:  # unset unless given
                    default = node.declare_parameter(full, None, ParameterDescriptor(dynamic_typing=True)).value
                    node.undeclare_parameter(full)
                if default is None:
                    # A statically typed parameter without a value breaks GetParameters for every name asked with
                    # it (rclpy answers nothing: ros2 param dump fails), so an unset override is declared
                    # dynamically typed; its type is still fixed: a value of another type is refused
                    # (:func:`wrong_type`), and once set it keeps the field's type.
                    desc.dynamic_typing = True
                    desc.type = Parameter.Type.NOT_SET.value
                    _EXPECTED_TYPES.setdefault(node, {})[full] = ros_type(spec['default'])
                    node.declare_parameter(full, None, desc)
                else:
                    declare_typed(node, full, typed_value(spec['default'], default), desc,
                                  _model_check(full, name))

    def current(self, proposed: Mapping[str, Any] | None = None) -> dict[str, AxisParams]:
        """Validated parameters of every axis, with ``proposed`` (full parameter names) taking precedence.

        Raises:
            ConfigError: naming ``model.<field>`` or ``axis.<joint>.<field>``.
        """
        proposed = proposed or {}

        def get(full: str) -> Any:
            if full in proposed:
                return proposed[full]
            return _value(self.node.get_parameter_or(full))

        model = {s['name']: get(f'model.{s["name"]}') for s in self.specs}
        try:
            base = AxisParams.from_mapping(model)
        except ConfigError as err:
            raise ConfigError(f'model.{err.parameter}', err.rule, err.value) from None
        out = {}
        for axis in self.axes:
            override = {s['name']: v for s in self.specs if (v := get(f'axis.{axis}.{s["name"]}')) is not None}
            try:
                out[axis] = AxisParams.from_mapping(override, base=base)
            except ConfigError as err:
                raise ConfigError(f'axis.{axis}.{err.parameter}', err.rule, err.value) from None
        return out

    @staticmethod
    def is_model_parameter(name: str) -> bool:
        return name.startswith(('model.', 'axis.'))


def split_parameters(params: Iterable[Parameter[Any]], *groups: Iterable[str]) -> list[dict[str, Any]]:
    """Values of ``params`` by group: first the model parameters (``model.*``, ``axis.*``), then one dict per
    group of setting names, in the order given; other names are left out."""
    sets = [set(g) for g in groups]
    out: list[dict[str, Any]] = [{} for _ in range(len(sets) + 1)]
    for p in params:
        if ModelParameters.is_model_parameter(p.name):
            out[0][p.name] = _value(p)
            continue
        for k, names in enumerate(sets, start=1):
            if p.name in names:
                out[k][p.name] = _value(p)
                break
    return out


def field_names(cls: type) -> frozenset[str]:
    """Names of the fields of a settings dataclass (= its parameter names)."""
    return frozenset(f.name for f in dataclasses.fields(cls))


def check_changes(params: Iterable[Parameter[Any]], *groups: tuple[type, Any]) -> list[dict[str, Any]]:
    """Validate the settings of a ``set_parameters`` request: each group (``(settings class, current
    settings)``) against its current values. Returns the values of each group (model parameters are the node's
    business: it builds and checks the whole new model).

    Raises:
        ConfigError: the first invalid value, naming the parameter and the rule it breaks.
    """
    split = split_parameters(params, *(field_names(cls) for cls, _ in groups))[1:]
    for values, (cls, current) in zip(split, groups, strict=True):
        if values:
            settings_from(cls, values, current)
    return split


def retime(node: Node, timer: Any, old_period_s: float, new_period_s: float, callback: Callable[[], None]) -> Any:
    """The timer to use after a period parameter changed: ``timer`` itself if the period is the same, else a
    new one (the old one cancelled)."""
    if new_period_s == old_period_s:
        return timer
    timer.cancel()
    return node.create_timer(new_period_s, callback)


def declare_settings(node: Node, cls: type[T], prefix: str = '') -> T:
    """Declare every field of the settings dataclass ``cls`` as a parameter and return the validated settings."""
    values = {}
    rules = SETTINGS_RULES.get(cls.__name__, {})
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]  # T is a settings dataclass: a TypeVar cannot be bound to "any dataclass"
        meta = f.metadata
        declare_typed(node, prefix + f.name, typed_value(f.default, f.default),
                      _descriptor(prefix + f.name, meta.get('unit', ''), meta.get('description', ''),
                                  default=f.default, rule=rules.get(f.name)),
                      settings_check(cls, f.name, prefix))
        values[f.name] = _value(node.get_parameter(prefix + f.name))
    return settings_from(cls, values)


def settings_check(cls: type, field: str, prefix: str) -> Callable[[Any], Any]:
    """The validation of setting ``field`` of ``cls`` alone, its error naming the parameter (``prefix + field``)."""
    def check(value: Any) -> None:
        try:
            settings_from(cls, {field: value})
        except ConfigError as err:
            raise ConfigError(prefix + err.parameter, err.rule, err.value) from None
    return check


def declare_typed(node: Node, name: str, default: Any, descriptor: ParameterDescriptor,
                  check: Callable[[Any], Any] | None = None) -> Parameter[Any]:
    """``node.declare_parameter`` with a statically typed ``descriptor``. A value given at start-up (a parameter
    override) that is a whole number for a double (or whole numbers for a list of doubles, a whole double for an
    integer) is taken as that value of the declared type, as on the command line (:func:`startup_overrides`); one
    of another wrong type or outside the descriptor's range is a ConfigError naming the parameter and the rule (one
    line), not rclpy's exception: ``check(value)`` (the validation of the value alone) words it where it can."""
    if node.has_parameter(name):   # declared by an earlier configure of a lifecycle node: its current value
        return node.get_parameter(name)
    kind = Parameter.Type(descriptor.type)
    given: Any = None
    ignore = False
    try:
        return node.declare_parameter(name, default, descriptor)
    except Exception as err:  # rclpy's InvalidParameterTypeException / InvalidParameterValueException
        if not (type(err).__module__.startswith('rclpy') and 'Parameter' in type(err).__name__):
            raise
        # read the value given (declared without type and range), then word the refusal or retype the value
        loose = None if isinstance(default, Parameter.Type) else default
        given = node.declare_parameter(name, loose, ParameterDescriptor(dynamic_typing=True)).value
        node.undeclare_parameter(name)
        if 'type' in type(err).__name__.lower():
            typed = _as_type(kind, given)
            if typed is None and check is not None:
                check(given)   # a value the validation refuses: its own words ("must be a whole number")
            if typed is None:
                given_kind = Parameter.Type.from_parameter_value(given)
                raise ConfigError(name, f'must be {_TYPE_WORDS.get(kind, kind.name.lower())}, not '
                                  f'{_TYPE_WORDS.get(given_kind, given_kind.name.lower())}', given) from None
            given, ignore = typed, True
    if ignore:
        try:
            return node.declare_parameter(name, given, descriptor, ignore_override=True)
        except Exception as err:
            if not (type(err).__module__.startswith('rclpy') and 'Parameter' in type(err).__name__):
                raise
    if check is not None:
        check(given)   # raises the validation's own ConfigError
    raise ConfigError(name, f'allowed: {descriptor.additional_constraints}', given)


def _as_type(kind: Parameter.Type, value: Any) -> Any:
    """``value`` as a parameter of type ``kind`` where that loses nothing (a whole number as a double or an integer,
    whole numbers as doubles), else None."""
    if kind == Parameter.Type.DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind == Parameter.Type.INTEGER and isinstance(value, float) and _whole_int64(value):
        return int(value)
    if kind == Parameter.Type.DOUBLE_ARRAY and (isinstance(value, (list, tuple)) or type(value).__name__ == 'array'):
        items = list(value)
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
            return [float(v) for v in items]
    return None


def describe_request(params: Iterable[Parameter[Any]]) -> str:
    """``name = value, ...`` of a ``set_parameters`` request (for a refusal that the core did not name)."""
    return ', '.join(f'{p.name} = {_value(p)!r}' for p in params)


def wrong_type(node: Node, param: Parameter[Any]) -> str | None:
    """The refusal of ``param`` for a declared, statically typed parameter of ``node`` when its type is not the
    declared one (one line naming the parameter, the type wanted and the type given), else None."""
    if not node.has_parameter(param.name) or param.type_ == Parameter.Type.NOT_SET:
        return None
    desc = node.describe_parameter(param.name)
    expected = _EXPECTED_TYPES.get(node, {}).get(param.name)
    if desc.dynamic_typing and expected is None:
        return None
    wanted = expected if desc.dynamic_typing and expected is not None else Parameter.Type(desc.type)
    if param.type_ == wanted:
        return None
    return (f'parameter {param.name!r} = {_value(param)!r}: must be {_TYPE_WORDS.get(wanted, wanted.name)}, '
            f'not {_TYPE_WORDS.get(param.type_, param.type_.name)} (its type is fixed: {wanted.name.lower()})')


def name_undeclared_parameters(node: Node, check: Callable[[list[Parameter[Any]]], SetParametersResult] | None
                               = None) -> None:
    """Refuse a ``set_parameters`` request in the node's own words before rclpy looks at it: a parameter ``node``
    does not declare is named, with the closest declared name (rclpy's own refusal reads "Invalid access to
    undeclared parameter(s): []"); a value of another type than the declared one is refused naming the parameter
    and both types (rclpy's reads "Wrong parameter type, expected 'Type.DOUBLE' got 'Type.INTEGER'"); then
    ``check`` (the node's validation: its reason, not rclpy's range message) runs.

    Why on the instance, not through rclpy's callbacks (checked against Kilted's ``rclpy/node.py``): rclpy's
    ``_set_parameters_atomically`` runs the pre-set callbacks, then raises ``ParameterNotDeclaredException`` for an
    undeclared name, then applies the descriptors (type, range, read-only: refused in rclpy's words), and only then
    calls the on-set callbacks (:func:`parameter_guard` installs one: it does validate the whole request at once,
    but after rclpy has refused what it refuses). A pre-set callback (``add_pre_set_parameters_callback``) may only
    return a changed list; an empty one is refused with rclpy's own reason ("parameter list cannot be empty ...").
    No public hook runs first and may refuse with a reason, so the two public methods every caller goes through
    are wrapped on the instance: the parameter services call :meth:`Node.set_parameters_atomically` (one parameter
    at a time for ``set_parameters``), in-process callers :meth:`Node.set_parameters`. What passes goes on to
    rclpy's own checks and callbacks unchanged.
    """
    original_atomically = node.set_parameters_atomically
    original_each = node.set_parameters

    def refusal(parameter_list: list[Parameter[Any]]) -> SetParametersResult | None:
        undeclared = [p.name for p in parameter_list if not node.has_parameter(p.name)]
        if undeclared:
            hint = did_you_mean(undeclared[0], sorted(node.list_parameters([], 0).names))
            names = ', '.join(repr(n) for n in undeclared)
            return SetParametersResult(successful=False, reason=f'parameter {names}: not a parameter of '
                                       f'{node.get_name()}{hint}; ros2 param list {node.get_fully_qualified_name()} '
                                       'lists them')
        if check is not None and not any(node.describe_parameter(p.name).read_only for p in parameter_list):
            result = check(parameter_list)   # first: a value the validation refuses is refused in its words
            if not result.successful:
                return result
        for p in parameter_list:
            reason = wrong_type(node, p)   # then a value it would take but of another type (1 for a double)
            if reason is not None:
                return SetParametersResult(successful=False, reason=reason)
        return None

    def set_parameters_atomically(parameter_list: list[Parameter[Any]]) -> SetParametersResult:
        refused = refusal(parameter_list)
        return refused if refused is not None else original_atomically(parameter_list)

    def set_parameters(parameter_list: list[Parameter[Any]]) -> list[SetParametersResult]:
        results = []
        for p in parameter_list:
            refused = refusal([p])
            results.extend([refused] if refused is not None else original_each([p]))
        return results

    setattr(node, 'set_parameters_atomically', set_parameters_atomically)  # noqa: B010 - an instance's method
    setattr(node, 'set_parameters', set_parameters)  # noqa: B010 - an instance's method


def parameter_guard(node: Node, validate: Callable[[list[Parameter[Any]]], None],
                    apply: Callable[[list[Parameter[Any]]], None]) -> None:
    """Install ``ros2 param set`` semantics: ``validate`` raises GimbalFrictionError to refuse (the old value stays
    and stays in effect), ``apply`` runs after a successful set. A refusal's reason names the parameter: a
    ConfigError does itself, any other error is prefixed with the request (``model.walther_a = 1.0: the lubricant
    viscosity ...``). An unexpected exception refuses too (counted as a callback error) rather than leaving the
    caller without an answer. A request for an undeclared parameter or with a value of the wrong type is refused
    naming it, and the validation runs before rclpy's range check, so its reason is the one given
    (:func:`name_undeclared_parameters`)."""
    if node.__dict__.get('_parameter_guard') is not None:   # installed by an earlier configure (same callbacks)
        return
    node.__dict__['_parameter_guard'] = (validate, apply)
    validated: list[tuple[tuple[str, int, str], ...]] = []  #: the request just validated by the pre-check

    def key(params: list[Parameter[Any]]) -> tuple[tuple[str, int, str], ...]:
        return tuple((p.name, p.type_.value, repr(_value(p))) for p in params)

    def on_set(params: list[Parameter[Any]]) -> SetParametersResult:
        if not getattr(node, 'configured', True):   # a lifecycle node not configured: its configure validates
            return SetParametersResult(successful=True)
        if validated and validated[-1] == key(params):  # the pre-check just validated this very request
            validated.clear()
            return SetParametersResult(successful=True)
        validated.clear()
        unset = [p.name for p in params if p.type_ == Parameter.Type.NOT_SET and node.has_parameter(p.name)]
        if unset:  # rclpy would undeclare it: the node could not read it any more
            return SetParametersResult(successful=False, reason=f'parameter {unset[0]!r} cannot be unset (rclpy '
                                       'would undeclare it); set a value (an axis override: the model.* value)')
        try:
            with np.errstate(all='ignore'):  # a model that overflows is refused with a reason, not warnings
                validate(params)
        except ConfigError as err:
            names = {p.name for p in params}
            if err.parameter in names or not names:
                return SetParametersResult(successful=False, reason=str(err))
            # a cross-field rule names the other field: say which value of the request broke it
            return SetParametersResult(successful=False, reason=f'{describe_request(params)}: {err}')
        except GimbalFrictionError as err:
            return SetParametersResult(successful=False, reason=f'{describe_request(params)}: {err}')
        except Exception as err:  # a bug must not leave a set_parameters call unanswered
            callback_failed(node, err)
            return SetParametersResult(successful=False, reason=f'{describe_request(params)}: internal error '
                                       f'{type(err).__name__}: {err}')
        return SetParametersResult(successful=True)

    def pre_check(params: list[Parameter[Any]]) -> SetParametersResult:
        validated.clear()
        result = on_set(params)
        if result.successful:
            validated.append(key(params))
        return result

    def post_set(params: list[Parameter[Any]]) -> None:
        validated.clear()
        if not getattr(node, 'configured', True):
            return
        try:
            apply(params)
        except Exception as err:  # pragma: no cover - validated before
            callback_failed(node, err)

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)
    name_undeclared_parameters(node, pre_check)


def check_model(axes: Mapping[str, AxisParams], t_min_c: float, t_max_c: float) -> None:
    """The whole model of every axis can be built over ``[t_min_c, t_max_c]`` °C (positive, finite viscosity and
    torque): :class:`~gimbal_friction.physics.table.FrictionTable` on a 1 °C grid. For a node that does not tabulate
    the model itself (the estimator) but shares its parameters.

    Raises:
        ModelDomainError: naming the axis.
    """
    step = max(1.0, (t_max_c - t_min_c) / 1000.0)
    for axis, params in axes.items():
        try:
            with np.errstate(all='ignore'):
                FrictionTable(params, t_min_c, t_max_c, step)
        except ModelDomainError as err:
            raise ModelDomainError(f'axis {axis}: {err}') from None


def startup_model_error(node: Node, err: GimbalFrictionError, defaults: Mapping[str, Any]) -> ModelDomainError:
    """A model that does not build at start-up, with the parameters whose values differ from their ``defaults``
    (name -> default): the ones to look at."""
    changed = []
    for name, default in defaults.items():
        if node.has_parameter(name):
            value = _value(node.get_parameter_or(name))
            if value is not None and value != default:
                changed.append(f'{name} = {value!r}')
    suffix = f' (set, not default: {", ".join(changed)})' if changed else ''
    return ModelDomainError(f'{err}{suffix}')


def settings_defaults(*classes: type) -> dict[str, Any]:
    """Parameter name -> default of every field of the settings dataclasses."""
    return {f.name: f.default for cls in classes for f in dataclasses.fields(cls)}


#: the signature rclpy reads as a "callback with message info" (message, MessageInfo)
_MESSAGE_WITH_INFO = inspect.Signature([inspect.Parameter('msg', inspect.Parameter.POSITIONAL_ONLY),
                                        inspect.Parameter('info', inspect.Parameter.POSITIONAL_ONLY)])


def subscribe(node: Node, counter: InputCounter, msg_type: Any, topic: str, callback: Callable[[Any], None],
              qos: Any, *, raw: bool = False, qos_overriding_options: Any = None) -> Any:
    """``node.create_subscription`` whose messages are counted by ``counter`` (received, lost) before
    ``callback(msg)`` runs (not for a message already received: see :meth:`InputCounter.count`).

    The message info (publisher sequence numbers) needs rclpy's "callback with message info" form, which rclpy
    infers from the callback's signature (two parameters). rclpy 9's EventsExecutor then passes the ``(msg, info)``
    tuple as one argument where the other executors pass two, so the wrapper takes either and *declares* the
    two-parameter signature (``__signature__``, which :func:`inspect.signature` reports) — no private state of
    rclpy is touched.
    """
    count = counter.count

    def on_message(*args: Any) -> None:
        msg, info = args if len(args) == 2 else args[0]
        if count(topic, info):
            callback(msg)

    on_message.__signature__ = _MESSAGE_WITH_INFO  # type: ignore[attr-defined]  # rclpy reads the callback's __signature__ to pass MessageInfo; functions declare no such attribute
    return node.create_subscription(msg_type, topic, on_message, qos, raw=raw,
                                    qos_overriding_options=qos_overriding_options)


def to_msg(one: diagnostics.Status) -> DiagnosticStatus:
    """A :class:`gimbal_friction.streams.diagnostics.Status` as the message."""
    return DiagnosticStatus(level=one.level, name=one.name, message=one.message, hardware_id=one.hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in one.values])


def _from_msg(msg: DiagnosticStatus) -> diagnostics.Status:
    return diagnostics.Status(msg.name, bytes(msg.level), msg.message, msg.hardware_id,
                              tuple((kv.key, kv.value) for kv in msg.values))


def status(name: str, level: bytes, message: str, hardware_id: str, values: Mapping[str, Any]) -> DiagnosticStatus:
    """A DiagnosticStatus with ``values`` as KeyValue strings (the text:
    :func:`gimbal_friction.streams.diagnostics.status`, floats with 6 significant digits)."""
    return to_msg(diagnostics.status(name, level, message, hardware_id, values))


def diagnostic_array(node: Node, statuses: Sequence[DiagnosticStatus]) -> DiagnosticArray:
    """The DiagnosticArray of ``statuses``, stamped now; a managed node's say its state
    (:func:`gimbal_friction.streams.diagnostics.with_lifecycle_state`)."""
    state = getattr(node, 'lifecycle_state', None)
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = [to_msg(one) for one in diagnostics.with_lifecycle_state([_from_msg(s) for s in statuses], state)]
    return msg


def stamp_to_s(stamp: Any) -> float:
    """builtin_interfaces/Time to seconds [s]."""
    return float(stamp.sec + 1e-9 * stamp.nanosec)


def callback_failed(node: Node, err: BaseException) -> None:
    """Count and log (once per kind) a callback that raised; the node keeps running. Nodes show the counts in
    ``/diagnostics`` (:func:`callback_error_values`)."""
    errors: dict[str, int] = node.__dict__.setdefault('callback_errors', {})
    key = f'{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ""}'[:200]
    if key not in errors:
        node.get_logger().error(f'callback failed (the node keeps running): {key}')
    errors[key] = errors.get(key, 0) + 1


def callback_error_values(node: Node) -> dict[str, int]:
    """``callback error: <kind>`` -> count, for ``/diagnostics``."""
    errors: dict[str, int] = node.__dict__.get('callback_errors', {})
    return {f'callback error: {k}': v for k, v in errors.items()}


def check_other_nodes_values(node: str, values: Mapping[str, Any]) -> None:
    """Refuse an invalid value of a parameter that ``node`` does not declare but another executable of the suite
    does (the shared file holds every node's parameters under ``/**``), with that node's rule: one rule for every
    node, so ``-p model.ball_count:=abc`` stops residual_logger as it stops friction_feedforward.

    The model parameters are checked together over the packaged file's (``model.*``, then ``axis.<joint>.*`` over
    them), the settings of each settings class together, chamber_replay's by type.

    Raises:
        ConfigError: naming the parameter and the rule it breaks.
    """
    from gimbal_friction.config.loader import CHAMBER_REPLAY_SPECS, node_parameter_names
    from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
    from gimbal_friction.estimation.estimator import EstimatorSettings
    from gimbal_friction.feedforward.rule import FeedforwardSettings
    from gimbal_friction.sim.config import RealtimeSettings, SimConfig

    axes = axis_names(values) if 'axes' in values else axis_names(load_parameters())
    own = node_parameter_names(node, axes)
    foreign = {name: value for name, value in values.items() if name not in own}
    if not foreign:
        return
    model_names = {spec['name'] for spec in parameter_specs()}
    model = {n[6:]: v for n, v in foreign.items() if n.startswith('model.') and n[6:] in model_names}
    overrides: dict[str, dict[str, Any]] = {}
    for name, value in foreign.items():
        parts = name.split('.')
        if parts[0] == 'axis' and len(parts) == 3 and parts[2] in model_names:
            overrides.setdefault(parts[1], {})[parts[2]] = value
    if model or overrides:
        try:
            base = AxisParams.from_mapping({**(load_parameters().get('model') or {}), **model})
        except ConfigError as err:
            raise ConfigError(f'model.{err.parameter}', err.rule, err.value) from None
        for axis, override in overrides.items():
            try:
                AxisParams.from_mapping(override, base=base)
            except ConfigError as err:
                raise ConfigError(f'axis.{axis}.{err.parameter}', err.rule, err.value) from None
    for cls in (FeedforwardSettings, FeedforwardNodeSettings, EstimatorSettings, EstimatorNodeSettings,
                LoggerSettings):
        given = {n: foreign[n] for n in field_names(cls) if n in foreign}
        if given:
            settings_from(cls, given)
    for sim_cls in (SimConfig, RealtimeSettings):
        given = {n: foreign[n] for n in field_names(sim_cls) if n in foreign}
        if given:
            sim_cls.from_mapping(given)
    kinds = {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string', list: 'a list'}
    for spec in CHAMBER_REPLAY_SPECS:
        name, default = spec['name'], spec['default']
        if name in foreign:
            value = foreign[name]
            ok = isinstance(value, type(default)) and not (isinstance(value, bool) and not isinstance(default, bool))
            if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
                ok = True
            if not ok:
                raise ConfigError(name, f'must be {kinds[type(default)]} (a parameter of chamber_replay)', value)


def startup_overrides(argv: Sequence[str], node_name: str) -> tuple[list[Parameter[Any]], dict[str, str]]:
    """Check the parameters the command line gives ``node_name`` and return the overrides rclpy must be given on
    top of rcl's (the values the user wrote last where rcl would keep another type's value; a whole number given
    for a double parameter, or whole numbers for a list of doubles, as doubles: the parameters' types are fixed),
    and where each value came from.

    Raises:
        ConfigError: a name no node of the suite declares, an axis override of a joint not in ``axes``, a name of
            another node given specifically to this one, a value rcl cannot take, or an invalid value of another
            node's parameter (:func:`check_other_nodes_values`).
    """
    cl = command_line_parameters(argv, node_name)
    check_parameter_names(node_name, cl.values, cl.node_specific, cl.sources)
    try:
        check_other_nodes_values(node_name, cl.values)
    except ConfigError as err:
        origin = cl.sources.get(err.parameter)
        if origin is None or 'from ' in err.rule:
            raise
        raise ConfigError(err.parameter, f'{err.rule} (from {origin})', err.value) from None
    from gimbal_friction.config.parameter_rules import field_default

    overrides = {name: cl.values[name] for name in cl.ignored_by_rcl}
    for name, value in cl.values.items():  # an integer for a double parameter (-p max_torque_nm:=1) is that double
        default = field_default(node_name, name)
        if default is not None and value is not None:
            typed = typed_value(default, overrides.get(name, value))
            if repr(typed) != repr(value):
                overrides[name] = typed
    return [Parameter(name, value=value) for name, value in overrides.items()], cl.sources


def wants_help(argv: Sequence[str]) -> bool:
    """``-h`` or ``--help`` among the program's own arguments (before ``--ros-args``; ``argv[0]`` is the
    program)."""
    own = list(argv[1:])
    if '--ros-args' in own:
        own = own[:own.index('--ros-args')]
    return any(arg in ('-h', '--help') for arg in own)


def node_help(exe: str, doc: str | None) -> str:
    """The ``--help`` text of executable ``exe``: usage, ``doc`` (the node module's docstring: what it subscribes
    and publishes) and every parameter with its default and unit
    (:func:`gimbal_friction.config.loader.node_parameter_specs`, the table the node declares from)."""
    from gimbal_friction.config.loader import node_parameter_specs

    lines = [f'usage: {exe} [-h] [--ros-args [--params-file FILE] [-p NAME:=VALUE] [-r FROM:=TO] ...]',
             f'       ros2 run gimbal_friction {exe} [--ros-args ...]', '']
    if doc:
        plain = re.sub(r':[a-z]+:`~?([^`]+)`', r'\1', inspect.cleandoc(doc)).replace('``', '')  # no Sphinx roles
        lines += [*plain.splitlines(), '']
    lines.append('parameters (name = default [unit]: description; set with -p NAME:=VALUE or --params-file):')
    for spec in node_parameter_specs(exe):
        default = 'unset' if spec['default'] is None else repr(spec['default'])
        unit = spec['unit'] if spec['unit'] not in ('', '-') else ''
        unit_txt = f' [{unit}]' if unit else ''
        lines.append(f'  {spec["name"]} = {default}{unit_txt}: {spec["description"]}')
    return '\n'.join(lines) + '\n'


def print_help_if_asked(exe: str, argv: Sequence[str], doc: str | None) -> bool:
    """Print :func:`node_help` on stdout and return True if ``argv`` asks for it (then the node must not start:
    ROS is not initialised)."""
    if not wants_help(argv):
        return False
    sys.stdout.write(node_help(exe, doc))
    return True



@contextlib.contextmanager
def _stderr_held() -> Iterator[list[bytes]]:
    """Hold back what is written to file descriptor 2 (where rcl's own logging writes) inside the block: the list
    yielded receives it. The caller writes it out or drops it.

    Why a file-descriptor swap: rcl prints its refusal of the arguments (``[ERROR] [rcl]: Failed to parse global
    arguments``) from C through rcutils' console output handler while ``rclpy.init`` runs. The one public lever,
    ``rclpy.logging.set_logger_level('rcl', FATAL)`` before the init (it does silence that line), would also hide
    rcl's warnings of a start that succeeds (which :func:`init_rclpy` shows as they were once the init has
    succeeded), would not cover the other loggers printing during the init, and would have to be undone without
    clobbering a ``--log-level rcl:=...`` the user gave; rclpy has no call that holds console output back and hands
    it over. So the process's stderr is held for the duration of the init, and only there.
    """
    sys.stderr.flush()
    saved = os.dup(2)
    held: list[bytes] = []
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield held
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            held.append(tmp.read())


def init_rclpy(exe: str, argv: Sequence[str], **kwargs: Any) -> bool:
    """``rclpy.init(args=argv, **kwargs)`` for executable ``exe``, with exactly one line on stderr when it fails.

    The command line's parameter files and ``-p`` rules are read first the way rcl reads them
    (:func:`~gimbal_friction.config.rcl.command_line_parameters`), so a file that cannot be read or parsed is named in
    the node's own words (``parameter file /x.yaml: cannot read: No such file or directory``). What rcl itself
    would print while refusing its arguments (``[ERROR] [rcl]: Failed to parse global arguments``, then the
    exception) is held back: the reason of the exception is the one line. Returns False (the line printed) when
    the node must not start.
    """
    try:
        command_line_parameters(argv, exe)
    except GimbalFrictionError as err:
        print(f'{exe}: error: {err}', file=sys.stderr)
        return False
    try:
        with _stderr_held() as held:
            rclpy.init(args=list(argv), **kwargs)
    except Exception as err:  # rclpy raises RCLError/RuntimeError on arguments rcl refuses
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        print(f'{exe}: error: cannot start: {first}', file=sys.stderr)
        return False
    if held and held[0]:  # what rcl printed while starting fine (a warning) is shown as it was
        sys.stderr.flush()
        os.write(2, held[0])
    return True


def run_node(exe: str, factory: Callable[..., Node], args: Sequence[str] | None = None, *,
             suite_node: str | None = None) -> int:
    """Standard ``main``: init, build the node, spin with the EventsExecutor, clean exit on SIGINT/SIGTERM.

    SIGINT and SIGTERM only *request* shutdown (a flag checked between callbacks): a signal never raises inside
    a callback, so a file being written (the residual log) is never left half-written. A bad parameter file or
    value ends the process with exit code 1 and one line on stderr (the command line is checked before rcl reads
    it, :func:`init_rclpy`).

    ``suite_node`` (the node's name in :data:`gimbal_friction.config.SUITE_NODES`) also checks the command line
    before the node starts (:func:`startup_overrides`): a parameter name no node of the suite declares is refused,
    and a ``-p`` value that rcl would silently drop because a parameter file set the name with another type is
    applied (and validated) instead of the file's value.
    """
    argv = list(sys.argv if args is None else args)
    if print_help_if_asked(exe, argv, getattr(sys.modules.get(factory.__module__), '__doc__', None)):
        return 0
    stop = threading.Event()

    def request_stop(signum: int, frame: Any) -> None:
        stop.set()

    overrides: list[Parameter[Any]] = []
    sources: dict[str, str] = {}
    try:
        if suite_node is not None:
            overrides, sources = startup_overrides(argv, suite_node)
    except GimbalFrictionError as err:
        print(f'{exe}: error: {err}', file=sys.stderr)
        return 1
    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    if not init_rclpy(exe, argv, signal_handler_options=SignalHandlerOptions.NO):
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        return 1
    node = None
    code = 0
    try:
        node = factory(parameter_overrides=overrides) if overrides else factory()
        from rclpy.experimental.events_executor import EventsExecutor
        executor = EventsExecutor()
        executor.add_node(node)
        # EventsExecutor.spin() busy-loops and misses signals with these wheels; a spin_once loop does not.
        while rclpy.ok() and not stop.is_set():
            try:
                executor.spin_once(timeout_sec=0.1)
            except (KeyboardInterrupt, ExternalShutdownException):
                raise
            except Exception as err:
                callback_failed(node, err)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except GimbalFrictionError as err:
        origin = sources.get(getattr(err, 'parameter', ''), '')
        where = f' (from {origin})' if origin and 'from ' not in str(err) else ''
        print(f'{exe}: error: {err}{where}', file=sys.stderr)
        code = 1
    except Exception as err:
        if type(err).__module__.startswith('rclpy') and 'Parameter' in type(err).__name__:
            print(f'{exe}: error: {err}'.splitlines()[0], file=sys.stderr)
            code = 1
        else:
            raise
    finally:
        if node is not None:
            close = getattr(node, 'close', None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return code
