"""Parameter files: load the packaged defaults and layer user files over them, key by key.

A parameter file is a ROS 2 parameters file (``node_name: ros__parameters:``). The model parameters shared by
every node and tool live under ``/**``::

    /**:
      ros__parameters:
        axes: [elevation]            # configured gimbal axes = joint names
        model:                       # model parameters of every axis (AxisParams fields)
          interference_mm: 0.006
        axis:                        # per-axis overrides of model.*
          azimuth:
            interference_mm: 0.004

Layering follows repeated ``--params-file``: later files override earlier ones key by key, so a user file holds
only what differs. The packaged defaults are read with :mod:`importlib.resources` (an editable install does not
install ``data_files``).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from collections.abc import Iterable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from gimbal_friction.common.errors import ConfigError, ConfigFileError
from gimbal_friction.common.text import did_you_mean
from gimbal_friction.config.rcl import read_parameter_file, yaml_error_text
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.inputs import unconfigured_joints

WILDCARD = '/**'
DEFAULTS_RESOURCE = 'gimbal_friction.yaml'


def packaged_defaults_text() -> str:
    """Text of the packaged ``config/gimbal_friction.yaml``."""
    return resources.files('gimbal_friction').joinpath('data', DEFAULTS_RESOURCE).read_text(encoding='utf-8')




#: PyYAML's safe loader on libyaml when PyYAML has it (the same documents, parsed about 15x faster)
_FAST_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def read_yaml(source: str | Path, text: str | None = None) -> dict[str, Any]:
    try:
        if text is None:   # (a regular file, a size limit, UTF-8: as --params-file)
            text = read_parameter_file(source)
        try:
            data = yaml.load(text, Loader=_FAST_LOADER)  # noqa: S506  # a safe loader (libyaml's: 15x faster)
        except yaml.YAMLError:
            data = yaml.safe_load(text)  # the error as PyYAML's own loader words it (the message users see)
    except OSError as err:
        msg = f'cannot read: {err.strerror}'
        raise ConfigFileError(str(source), msg) from None
    except UnicodeDecodeError:
        msg = 'not a parameter file: not UTF-8 text (a binary file?)'
        raise ConfigFileError(str(source), msg) from None
    except yaml.YAMLError as err:
        msg = f'not valid YAML: {yaml_error_text(err)}'
        raise ConfigFileError(str(source), msg) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigFileError(str(source), 'a parameter file must map node names to {ros__parameters: ...}')
    return data


def deep_merge(base: dict[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Merge ``over`` into a copy of ``base`` key by key (nested mappings merged, everything else replaced)."""
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _sections(data: Mapping[str, Any], source: str, node_name: str | None) -> list[dict[str, Any]]:
    wanted = [WILDCARD, '/' + WILDCARD.strip('/'), '**']
    if node_name:
        wanted += [node_name, '/' + node_name]
    out = []
    for key in data:
        if key in wanted:
            section = data[key]
            if not isinstance(section, Mapping) or 'ros__parameters' not in section:
                raise ConfigError(f'{source}: {key}', 'section must hold a ros__parameters mapping')
            params = section['ros__parameters']
            if params is None:
                continue
            if not isinstance(params, Mapping):
                raise ConfigError(f'{source}: {key}.ros__parameters', 'must be a mapping')
            out.append(dict(params))
    return out


def load_parameters(paths: Iterable[str | Path] = (), *, node_name: str | None = None,
                    include_defaults: bool = True) -> dict[str, Any]:
    """Merged ``ros__parameters`` of the packaged defaults and ``paths``, in order.

    For each file the ``/**`` section is applied, then the section of ``node_name`` (if given), as ROS does.

    Raises:
        ConfigError: unreadable file, invalid YAML, or a malformed section.
    """
    merged: dict[str, Any] = {}
    layers: list[tuple[str, dict[str, Any]]] = []
    if include_defaults:
        layers.append(('packaged defaults', read_yaml('packaged defaults', packaged_defaults_text())))
    layers += [(str(p), read_yaml(p)) for p in paths]
    for source, data in layers:
        for section in _sections(data, source, node_name):
            merged = deep_merge(merged, section)
    return merged


def axis_names(params: Mapping[str, Any]) -> list[str]:
    """Configured axis (joint) names, in order.

    Raises:
        ConfigError: ``axes`` missing, empty, not a list of unique non-empty names.
    """
    axes = params.get('axes')
    if isinstance(axes, str):
        axes = [axes]
    if not isinstance(axes, list) or not axes:
        raise ConfigError('axes', 'must be a non-empty list of joint names', axes)
    if not all(isinstance(a, str) and a.strip() for a in axes):
        raise ConfigError('axes', 'joint names must be non-empty strings', axes)
    if len(set(axes)) != len(axes):
        raise ConfigError('axes', 'joint names must be unique', axes)
    return list(axes)


def _flat(prefix: str, section: Any) -> dict[str, Any]:
    if section is None:
        return {}
    if not isinstance(section, Mapping):
        raise ConfigError(prefix, 'must be a mapping of model parameters', section)
    for key, value in section.items():
        if isinstance(value, Mapping):
            raise ConfigError(f'{prefix}.{key}', 'model parameters are flat: unexpected nested mapping')
    return dict(section)


def axis_params(params: Mapping[str, Any], axis: str) -> AxisParams:
    """Validated :class:`AxisParams` of ``axis``: ``model.*`` with ``axis.<axis>.*`` layered over it.

    Raises:
        ConfigError: unknown axis, unknown parameter or impossible value; the parameter name carries its
            section (``model.ball_diameter_mm``, ``axis.azimuth.interference_mm``).
    """
    names = axis_names(params)
    refused = unconfigured_joints([axis], names)
    if refused:
        raise ConfigError('axes', refused)
    model = _flat('model', params.get('model'))
    overrides_all = params.get('axis') or {}
    if not isinstance(overrides_all, Mapping):
        raise ConfigError('axis', 'must map axis names to parameter overrides', overrides_all)
    override = _flat(f'axis.{axis}', overrides_all.get(axis))
    try:
        base = AxisParams.from_mapping(model)
    except ConfigError as err:
        raise ConfigError(f'model.{err.parameter}', err.rule, err.value) from None
    try:
        return AxisParams.from_mapping(override, base=base)
    except ConfigError as err:
        raise ConfigError(f'axis.{axis}.{err.parameter}', err.rule, err.value) from None


def all_axis_params(params: Mapping[str, Any]) -> dict[str, AxisParams]:
    """:func:`axis_params` of every configured axis, in configured order."""
    return {name: axis_params(params, name) for name in axis_names(params)}


def _yaml_value(value: Any) -> Any:
    if isinstance(value, float):
        return float(repr(value)) if math.isfinite(value) else value
    return value


def render_parameter_file(model: Mapping[str, Any] | None = None, axes_overrides: Mapping[str, Mapping[str, Any]]
                          | None = None, *, axes: list[str] | None = None, header: str = '') -> str:
    """Text of a layerable parameter file with ``model.*`` and ``axis.<name>.*`` values under ``/**``.

    Floats are written with a decimal point so ROS reads them as doubles.
    """
    body: dict[str, Any] = {}
    if axes is not None:
        body['axes'] = list(axes)
    if model:
        body['model'] = {k: _yaml_value(v) for k, v in model.items()}
    if axes_overrides:
        body['axis'] = {a: {k: _yaml_value(v) for k, v in vals.items()} for a, vals in axes_overrides.items()}
    doc = {WILDCARD: {'ros__parameters': body}}
    lines = ''.join(f'# {line}\n' if line else '#\n' for line in header.splitlines())
    text: str = yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    return lines + text


# ---------------------------------------------------------------------------------------------------- parameter names
#: the executables of the suite whose parameters may share a file (packaged file: everything under ``/**``)
SUITE_NODES = ('friction_feedforward', 'friction_estimator', 'residual_logger', 'chamber_replay', 'gimbal_sim')
#: parameters of chamber_replay: name, default, unit, description (the node declares them from this table)
CHAMBER_REPLAY_SPECS: tuple[dict[str, Any], ...] = (
    {'name': 'bag', 'default': '', 'unit': '', 'description': 'chamber-test bag: rosbag2 folder, .mcap or .db3 file '
     '(required)'},
    {'name': 'rate', 'default': 1.0, 'unit': '-', 'description': 'playback rate factor (2 = twice as fast), > 0'},
    {'name': 'loop', 'default': False, 'unit': '', 'description': 'start again at the end of the bag'},
    {'name': 'start_offset_s', 'default': 0.0, 'unit': 's', 'description': 'skip this much of the bag, from 0 to '
     "the bag's duration"},
    {'name': 'topic_map', 'default': [''], 'unit': '', 'description': "'contract_topic=bag_topic' remaps of bag "
     'topics'},
    {'name': 'topics', 'default': [''], 'unit': '', 'description': "topics to publish besides the three inputs; "
     "'*' = every topic whose message type is installed"},
    {'name': 'exclude_topics', 'default': [''], 'unit': '', 'description': 'topics not to publish'},
    {'name': 'wait_for_subscribers', 'default': 0, 'unit': '-', 'description': 'wait for this many subscribers on '
     '/joint_states before playing (>= 0; 0 = do not wait)'},
    {'name': 'wait_timeout_s', 'default': 30.0, 'unit': 's', 'description': 'give up waiting for subscribers '
     'after this long, > 0'},
)
#: parameters of chamber_replay (gimbal_friction.nodes.chamber_replay)
CHAMBER_REPLAY_PARAMETERS = tuple(spec['name'] for spec in CHAMBER_REPLAY_SPECS)
#: the read-only ``axes`` parameter of the nodes that know joints
AXES_DESCRIPTION = 'configured gimbal axes = joint names in /joint_states (read-only)'
#: the ``autostart`` parameter of the managed (lifecycle) nodes (gimbal_friction.nodes._lifecycle)
AUTOSTART_DESCRIPTION = ('configure and activate the node at start-up (read-only; false: wait unconfigured for a '
                         'lifecycle manager)')
#: the executables that are lifecycle nodes, and their lifecycle parameter
MANAGED_NODES = ('friction_feedforward', 'friction_estimator', 'residual_logger')
LIFECYCLE_SPECS: tuple[dict[str, Any], ...] = (
    {'name': 'autostart', 'default': True, 'unit': '', 'description': AUTOSTART_DESCRIPTION},
)
#: parameters every rclpy node declares itself
ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')
MODEL_PARAMETERS = tuple(f.name for f in dataclasses.fields(AxisParams))


def flat_parameters(params: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """ROS parameter names of a merged ``ros__parameters`` mapping (:func:`load_parameters`): nested mappings
    joined with dots, as the nodes declare them (for :func:`check_parameter_names` in a tool).

    >>> flat_parameters({'axes': ['elevation'], 'model': {'ball_count': 15}, 'axis': {'elevation': {'width_mm': 5.0}}})
    {'axes': ['elevation'], 'model.ball_count': 15, 'axis.elevation.width_mm': 5.0}
    """
    out: dict[str, Any] = {}
    for key, value in params.items():
        if isinstance(value, Mapping) and value:
            out.update(flat_parameters(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


@functools.lru_cache(maxsize=1)
def _packaged_flat() -> tuple[tuple[str, ...], Mapping[str, Any]]:
    """The packaged file's axes and flat parameter values (read once; not to be modified)."""
    packaged = load_parameters()
    return tuple(axis_names(packaged)), flat_parameters(packaged)


def node_parameter_specs(node: str) -> list[dict[str, Any]]:
    """Name, default, unit and description of every parameter executable ``node`` of the suite declares (the
    defaults of the packaged file where it sets them), in declaration order; the per-joint overrides of the
    model are one entry named ``axis.<joint>.<field>``. The one table behind ``--help`` and the name checks.

    Raises:
        ConfigError: ``node`` is not an executable of the suite.
    """
    from gimbal_friction.config.node_settings import (
        FEEDFORWARD_PREFIXED,
        RETIRED_DEFAULTS,
        RETIRED_PARAMETERS,
        EstimatorNodeSettings,
        FeedforwardNodeSettings,
        LoggerSettings,
    )
    from gimbal_friction.estimation.estimator import EstimatorSettings
    from gimbal_friction.feedforward.rule import FeedforwardSettings
    from gimbal_friction.physics.params import parameter_specs

    packaged_axes, flat = _packaged_flat()
    managed = [dict(spec) for spec in LIFECYCLE_SPECS]

    def fields(*classes: Any) -> list[dict[str, Any]]:
        return [{'name': f.name, 'default': flat.get(f.name, f.default), 'unit': f.metadata.get('unit', ''),
                 'description': f.metadata.get('description', '')} for cls in classes for f in dataclasses.fields(cls)]

    axes = [{'name': 'axes', 'default': list(packaged_axes), 'unit': '', 'description': AXES_DESCRIPTION}]
    model = [{'name': f'model.{spec["name"]}', 'default': flat.get(f'model.{spec["name"]}', spec['default']),
              'unit': spec.get('unit', ''), 'description': spec.get('description', '')} for spec in parameter_specs()]
    model.append({'name': 'axis.<joint>.<field>', 'default': None, 'unit': '', 'description': 'override of '
                  'model.<field> for one joint of axes (unset unless given)'})
    if node == 'friction_feedforward':
        prefixed = [{'name': prefix + f.name, 'default': flat.get(prefix + f.name, f.default),
                     'unit': f.metadata.get('unit', ''), 'description': f.metadata.get('description', '')}
                    for prefix, cls in FEEDFORWARD_PREFIXED for f in dataclasses.fields(cls)]
        retired = [{'name': name, 'default': RETIRED_DEFAULTS[name], 'unit': '-', 'retired': True,
                    'description': f'retired, no effect: {why}'} for name, why in RETIRED_PARAMETERS.items()]
        return axes + model + fields(FeedforwardSettings, FeedforwardNodeSettings) + prefixed + retired + managed
    if node == 'friction_estimator':
        return axes + model + fields(EstimatorSettings, EstimatorNodeSettings) + managed
    if node == 'residual_logger':
        return axes + fields(LoggerSettings) + managed
    if node == 'chamber_replay':
        return [dict(spec) for spec in CHAMBER_REPLAY_SPECS]
    if node == 'gimbal_sim':
        from gimbal_friction.sim.config import parameter_specs as sim_specs
        sim = [{'name': spec['name'], 'default': spec['default'], 'unit': spec.get('unit', ''),
                'description': spec.get('description', '')} for spec in sim_specs(node=True)]
        return axes + model + sim
    raise ConfigError('node', f'not an executable of the suite ({", ".join(SUITE_NODES)})', node)


def node_parameter_names(node: str, axes: Sequence[str]) -> frozenset[str]:
    """Every parameter name executable ``node`` of the suite declares, with ``axes`` configured."""
    names: set[str] = set(ROS_PARAMETERS)
    for spec in node_parameter_specs(node):
        if spec['name'] == 'axis.<joint>.<field>':
            names |= {f'axis.{a}.{n}' for a in axes for n in MODEL_PARAMETERS}
        else:
            names.add(spec['name'])
    return frozenset(names)


#: the QoS policies every publisher and subscription of the nodes takes as a parameter
#: ``qos_overrides.<topic>.<publisher|subscription>.<policy>`` (rclpy's default policies), with their allowed values
#: (``depth``: a whole number >= 1). ``best_available`` on a subscription: follow the publishers' reliability.
QOS_OVERRIDE_POLICIES: dict[str, tuple[str, ...]] = {
    'history': ('keep_last', 'keep_all', 'system_default'),
    'depth': (),
    'reliability': ('reliable', 'best_effort', 'best_available', 'system_default'),
}
QOS_OVERRIDES = 'qos_overrides.'


def check_qos_override(name: str, value: Any) -> None:
    """Refuse a ``qos_overrides.*`` parameter the nodes would ignore or could not apply: not of the form
    ``qos_overrides./<topic>.<publisher|subscription>.<policy>``, a policy other than
    :data:`QOS_OVERRIDE_POLICIES`, or a value that policy does not take.

    >>> check_qos_override('qos_overrides./joint_states.subscription.reliability', 'best_effort')
    >>> check_qos_override('qos_overrides./joint_states.subscription.durability', 'volatile')
    Traceback (most recent call last):
    ...
    gimbal_friction.common.errors.ConfigError: parameter 'qos_overrides./joint_states.subscription.durability' = \
'volatile': not overridable (the nodes take history, depth, reliability)

    Raises:
        ConfigError: naming the parameter and the rule.
    """
    parts = name[len(QOS_OVERRIDES):].split('.') if name.startswith(QOS_OVERRIDES) else []
    if len(parts) != 3 or parts[1] not in ('publisher', 'subscription'):
        raise ConfigError(name, 'a QoS override is qos_overrides.<topic>.<publisher|subscription>.<policy>', value)
    topic, _, policy = parts
    if not topic.startswith('/'):
        raise ConfigError(name, f'the topic must be fully qualified (/{topic}): rclpy matches the resolved name',
                          value)
    if policy not in QOS_OVERRIDE_POLICIES:
        raise ConfigError(name, f'not overridable (the nodes take {", ".join(QOS_OVERRIDE_POLICIES)})', value)
    allowed = QOS_OVERRIDE_POLICIES[policy]
    if allowed and value not in allowed:
        raise ConfigError(name, f'must be one of {", ".join(allowed)}', value)
    if not allowed and (not isinstance(value, int) or isinstance(value, bool) or value < 1):
        raise ConfigError(name, 'must be a whole number >= 1', value)


def check_config_files(paths: Iterable[str | Path]) -> None:
    """Refuse a name in ``paths`` that no executable of the suite would read (a typo a tool would ignore).

    The ``/**`` section of each file may hold any suite node's parameters; a section naming a suite node
    (``friction_estimator:``) only that node's. Sections of other nodes are not the suite's business.

    Raises:
        ConfigError: an unreadable file, or the parameter, the closest known name and the file it came from.
    """
    paths = list(paths)
    if not paths:
        return
    axes = load_parameters(paths).get('axes')
    for path in paths:
        for key, section in read_yaml(path).items():
            name = str(key).strip('/')
            if name == '**':
                node, specific = SUITE_NODES[0], False
            elif name in SUITE_NODES:
                node, specific = name, True
            else:
                continue
            values = (section or {}).get('ros__parameters') if isinstance(section, Mapping) else None
            if not isinstance(values, Mapping):
                continue  # a malformed section is refused by load_parameters with its own reason
            flat = flat_parameters(values)
            if axes is not None:
                flat.setdefault('axes', axes)
            check_parameter_names(node, flat, flat if specific else (), {n: str(path) for n in flat})


def check_parameter_names(node: str, values: Mapping[str, Any], node_specific: Iterable[str] = (),
                          sources: Mapping[str, str] | None = None) -> None:
    """Refuse a parameter name that would be silently ignored by executable ``node``.

    A name is accepted if ``node`` declares it, or if another executable of the suite does and it was not given
    specifically to ``node`` (a section or ``-p`` rule naming it, ``node_specific``): the packaged file holds every
    node's settings under ``/**``. ``axis.<joint>.*`` must name a joint of ``axes`` (``values['axes']`` or the
    packaged default).

    Raises:
        ConfigError: naming the parameter, with the closest known name as a hint and where the value came from.
    """
    sources = sources or {}
    specific = set(node_specific)
    if 'axes' in values:
        try:
            axes = axis_names(values)
        except ConfigError as err:
            origin = f' (from {sources["axes"]})' if 'axes' in sources else ''
            raise ConfigError(err.parameter, f'{err.rule}{origin}', err.value) from None
    else:
        axes = axis_names(load_parameters())
    own = node_parameter_names(node, axes)
    others = {other: node_parameter_names(other, axes) for other in SUITE_NODES if other != node}
    everything = own.union(*others.values())
    for name in sorted(values):
        if name in own:
            continue
        origin = f' (from {sources[name]})' if name in sources else ''
        if name.startswith(QOS_OVERRIDES):   # every node's publishers and subscriptions take them
            try:
                check_qos_override(name, values[name])
            except ConfigError as err:
                raise ConfigError(name, f'{err.rule}{origin}', values[name]) from None
            continue
        owners = [other for other, names in others.items() if name in names]
        if owners and name not in specific:
            continue
        if owners:
            raise ConfigError(name, f'is a parameter of {", ".join(owners)}, not of {node}{origin}', values[name])
        parts = name.split('.')
        if parts[0] == 'axis' and len(parts) == 3 and parts[2] in MODEL_PARAMETERS:
            rule = f'{unconfigured_joints([parts[1]], axes)}: add it to axes{origin}'
            raise ConfigError(name, rule, values[name])
        hint = did_you_mean(name, sorted(everything))
        raise ConfigError(name, f'unknown parameter{hint}{origin}', values[name])
