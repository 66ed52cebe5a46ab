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
import math
from collections.abc import Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from gimbal_friction.core.errors import ConfigError
from gimbal_friction.core.params import AxisParams

WILDCARD = '/**'
DEFAULTS_RESOURCE = 'gimbal_friction.yaml'


def packaged_defaults_text() -> str:
    """Text of the packaged ``config/gimbal_friction.yaml``."""
    return resources.files('gimbal_friction').joinpath('data', DEFAULTS_RESOURCE).read_text(encoding='utf-8')


def yaml_error_text(err: yaml.YAMLError) -> str:
    """A YAML error on one line: what is wrong and where (PyYAML's own message spans several lines).

    >>> try:
    ...     yaml.safe_load('a: [1, 2' + chr(10) + 'b: 3')
    ... except yaml.YAMLError as err:
    ...     print(yaml_error_text(err))
    line 2, column 2: expected ',' or ']', but got ':' (while parsing a flow sequence that starts at line 1)
    """
    problem = getattr(err, 'problem', None)
    mark = getattr(err, 'problem_mark', None)
    context = getattr(err, 'context', None)
    context_mark = getattr(err, 'context_mark', None)
    if problem is None:
        return ' '.join(str(err).split())
    where = f'line {mark.line + 1}, column {mark.column + 1}: ' if mark is not None else ''
    text = f'{where}{" ".join(str(problem).split())}'
    if context:
        at = f' that starts at line {context_mark.line + 1}' if context_mark is not None else ''
        text += f' ({" ".join(str(context).split())}{at})'
    return text


def _read_yaml(source: str | Path, text: str | None = None) -> dict[str, Any]:
    try:
        if text is None:
            text = Path(source).read_text(encoding='utf-8')
        data = yaml.safe_load(text)
    except OSError as err:
        msg = f'cannot read parameter file: {err.strerror}'
        raise ConfigError(str(source), msg) from None
    except UnicodeDecodeError:
        msg = 'not a parameter file: not UTF-8 text (a binary file?)'
        raise ConfigError(str(source), msg) from None
    except yaml.YAMLError as err:
        msg = f'not valid YAML: {yaml_error_text(err)}'
        raise ConfigError(str(source), msg) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(str(source), 'a parameter file must map node names to {ros__parameters: ...}')
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
        layers.append(('packaged defaults', _read_yaml('packaged defaults', packaged_defaults_text())))
    layers += [(str(p), _read_yaml(p)) for p in paths]
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
    if axis not in names:
        raise ConfigError('axes', f'axis {axis!r} is not configured (configured: {", ".join(names)})')
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
