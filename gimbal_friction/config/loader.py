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
import ctypes
import dataclasses
import difflib
import functools
import math
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from gimbal_friction.common.errors import ConfigError, ConfigFileError
from gimbal_friction.physics.params import AxisParams

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


#: PyYAML's safe loader on libyaml when PyYAML has it (the same documents, parsed about 15x faster)
_FAST_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def read_yaml(source: str | Path, text: str | None = None) -> dict[str, Any]:
    try:
        if text is None:
            text = Path(source).read_text(encoding='utf-8')
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


# ---------------------------------------------------------------------------------------------------- the nodes' view
# The nodes get their parameter overrides from rcl, which merges every --params-file and -p of the command line into
# one table. Two of its rules surprise users and are mirrored here so that a node can tell what the user asked for:
#
# 1. A scalar is typed by its spelling (rcl_yaml_param_parser ``get_value``: true/yes/on..., strtol base 0, strtod,
#    else a string; quoted scalars are strings). ``1e-5`` is a double there, a string for PyYAML.
# 2. A value of another type than the one already set for a name does not replace it: rcl keeps one slot per type
#    and rclpy reads the first one set in the order bool, integer, double, string, arrays. So after
#    ``--params-file config.yaml -p model.ball_count:=15.5`` the node gets the file's integer 15, silently.
#
# :func:`command_line_parameters` resolves the command line the way rcl and rclpy do, and also records the value the
# user wrote last for each name; :func:`check_parameter_names` refuses names no node of the suite declares.

_RCL_TRUE = frozenset(('Y', 'y', 'yes', 'Yes', 'YES', 'true', 'True', 'TRUE', 'on', 'On', 'ON'))
_RCL_FALSE = frozenset(('N', 'n', 'no', 'No', 'NO', 'false', 'False', 'FALSE', 'off', 'Off', 'OFF'))
_RCL_SPECIAL_FLOATS = frozenset(f'{sign}.{word}' for sign in ('', '+', '-') for word in ('nan', 'NaN', 'NAN', 'inf',
                                                                                        'Inf', 'INF'))
_INT_RE = re.compile(r'\s*[+-]?(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)')
_FLOAT_RE = re.compile(r'\s*[+-]?((\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|inf(inity)?|nan(\(\w*\))?)', re.IGNORECASE)
_HEX_FLOAT_RE = re.compile(r'\s*[+-]?0[xX]([0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)([pP][+-]?\d+)?')


def _libc_strto() -> tuple[Any, Any] | None:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        strtol, strtod = libc.strtol, libc.strtod
    except (OSError, AttributeError):  # pragma: no cover - not a POSIX libc
        return None
    strtol.restype, strtol.argtypes = ctypes.c_long, [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p), ctypes.c_int]
    strtod.restype, strtod.argtypes = ctypes.c_double, [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p)]
    return strtol, strtod


_LIBC = _libc_strto()


def _strtol(text: str) -> int | None:
    """C ``strtol(text, &end, 0)`` when it consumes all of ``text`` without overflow, else None."""
    if _LIBC is not None and '\0' not in text:
        raw = text.encode('utf-8')
        end = ctypes.c_char_p()
        ctypes.set_errno(0)
        value = _LIBC[0](raw, ctypes.byref(end), 0)
        rest = end.value or b''
        ok = ctypes.get_errno() == 0 and len(rest) < len(raw) and not rest
        return int(value) if ok else None
    if not _INT_RE.fullmatch(text):
        return None
    value = int(text.strip(), 0) if not re.fullmatch(r'\s*[+-]?0[0-7]+', text) else int(text.strip(), 8)
    return value if -2**63 <= value < 2**63 else None


def _strtod(text: str) -> float | None:
    """C ``strtod(text, &end)`` when it consumes all of ``text`` without overflow or underflow, else None."""
    if _LIBC is not None and '\0' not in text:
        raw = text.encode('utf-8')
        end = ctypes.c_char_p()
        ctypes.set_errno(0)
        value = _LIBC[1](raw, ctypes.byref(end))
        rest = end.value or b''
        return float(value) if ctypes.get_errno() == 0 and len(rest) < len(raw) and not rest else None
    if _HEX_FLOAT_RE.fullmatch(text):
        value = float.fromhex(text.strip())
    elif _FLOAT_RE.fullmatch(text):
        value = float(re.sub(r'\(\w*\)', '', text.strip()))
    else:
        return None
    if math.isnan(value):
        return value
    if math.isinf(value):
        return value if 'inf' in text.lower() else None  # overflow (ERANGE)
    mantissa = re.sub(r'[eEpP][+-]?\d+$', '', text.strip()).lower().replace('0x', '')
    if abs(value) < sys.float_info.min and any(c in '123456789abcdef' for c in mantissa):
        return None  # underflow (glibc sets ERANGE for subnormal results too)
    return value


def rcl_scalar(text: str, quoted: bool = False) -> bool | int | float | str:
    """A YAML scalar the way rcl types it (``rcl_yaml_param_parser``: the nodes' parameter overrides).

    Unquoted: ``true/yes/on`` (and capitalised forms) and their opposites are booleans, then whatever C ``strtol``
    (base 0: ``0x10`` is 16, ``010`` is 8) reads completely and without overflow is an integer, then whatever
    ``strtod`` reads completely without overflow or underflow is a double (``1e-5``, ``nan``, ``.inf``); anything
    else, and every quoted scalar, is a string (``1e400`` is the string '1e400').

    >>> [rcl_scalar(t) for t in ('yes', '0x10', '010', '1e-5', '1e400', '15.5', 'abc')]
    [True, 16, 8, 1e-05, '1e400', 15.5, 'abc']
    >>> rcl_scalar('1.0', quoted=True)
    '1.0'
    """
    if quoted:
        return text
    if text in _RCL_TRUE:
        return True
    if text in _RCL_FALSE:
        return False
    value = _strtol(text)
    if value is not None:
        return value
    if text in _RCL_SPECIAL_FLOATS:
        special = float(text.lstrip('+-.'))
        return -special if text.startswith('-') else special
    real = _strtod(text)
    return real if real is not None else text


def _rcl_value(node: Any, where: str) -> Any:
    """A parameter value (scalar or sequence of one type) from a composed YAML node, rcl's way."""
    if isinstance(node, yaml.ScalarNode):
        if node.style is None and node.value == '':
            raise ConfigError(where, 'has no value')
        return rcl_scalar(node.value, quoted=node.style in ("'", '"'))
    if isinstance(node, yaml.SequenceNode):
        items: list[Any] = []
        stack = list(node.value)
        while stack:  # rcl flattens nested sequences
            item = stack.pop(0)
            if isinstance(item, yaml.SequenceNode):
                stack[:0] = item.value
            elif isinstance(item, yaml.ScalarNode):
                items.append(_rcl_value(item, where))
            else:
                raise ConfigError(where, 'a list may hold only values, not mappings')
        kinds = {type(v) for v in items}
        if len(kinds) > 1:
            raise ConfigError(where, 'list values must all be of one type (rcl)', items)
        return items
    raise ConfigError(where, 'must be a value or a list of values')


def _flat_parameters(node: Any, prefix: str, where: str, out: dict[str, Any]) -> None:
    if not isinstance(node, yaml.MappingNode):
        raise ConfigError(where, 'ros__parameters must be a mapping')
    for key, value in node.value:
        name = f'{prefix}{key.value}'
        if isinstance(value, yaml.MappingNode) and value.value:
            _flat_parameters(value, name + '.', where, out)
        elif isinstance(value, yaml.MappingNode):
            out[name] = None  # ``name: {}``: rcl declares it without a value
        else:
            out[name] = _rcl_value(value, f'{where}: {name}')


def ros_parameter_sections(text: str, source: str) -> list[tuple[str, dict[str, Any]]]:
    """The ``(node name, {parameter: value})`` sections of a ROS 2 parameters file, in file order, with the values
    typed as rcl types them (:func:`rcl_scalar`) and nested keys joined with dots (``model.ball_count``). Node names
    of nested namespaces are joined with ``/``.

    Raises:
        ConfigError: invalid YAML or not a parameters file, naming ``source``.
    """
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as err:
        raise ConfigFileError(source, f'not valid YAML: {yaml_error_text(err)}') from None
    out: list[tuple[str, dict[str, Any]]] = []

    def walk(node: Any, namespace: list[str]) -> None:
        if not isinstance(node, yaml.MappingNode):
            raise ConfigFileError(source, 'a parameter file must map node names to {ros__parameters: ...}')
        for key, value in node.value:
            if not isinstance(value, yaml.MappingNode):
                raise ConfigError(f'{source}: {key.value}', 'section must hold a ros__parameters mapping')
            keys = [k.value for k, _ in value.value]
            if 'ros__parameters' in keys:
                name = '/'.join([*namespace, str(key.value)])
                params: dict[str, Any] = {}
                for k, v in value.value:
                    if k.value == 'ros__parameters':
                        _flat_parameters(v, '', f'{source}: {name}', params)
                out.append((name, params))
            else:
                walk(value, [*namespace, str(key.value)])

    if root is not None:
        walk(root, [])
    return out


#: rclpy's types of a parameter value, in the order it reads rcl's per-type slots
_SLOT_ORDER = ('bool', 'int', 'float', 'str', 'bool[]', 'int[]', 'float[]', 'str[]')


def _slot(value: Any) -> str | None:
    if isinstance(value, list):
        return f'{type(value[0]).__name__}[]' if value else None
    if value is None:
        return None
    return type(value).__name__


class _Variant:
    """What rcl holds for one name in one section: a value per type, and the one written last."""

    def __init__(self) -> None:
        self.slots: dict[str, Any] = {}
        self.last: Any = None
        self.where = ''

    def write(self, value: Any, where: str) -> None:
        kind = _slot(value)
        if kind is not None:
            self.slots[kind] = value
        self.last, self.where = value, where

    def rclpy_value(self) -> Any:
        for kind in _SLOT_ORDER:
            if kind in self.slots:
                return self.slots[kind]
        return None


class CommandLineParameters(NamedTuple):
    """The parameters a node gets from its command line (see :func:`command_line_parameters`)."""

    node: str                       #: fully qualified node name, e.g. ``/friction_feedforward``
    values: dict[str, Any]          #: name -> the value written last for it (what the user asked for)
    sources: dict[str, str]         #: name -> where that value was written (``-p ...`` or the file)
    node_specific: frozenset[str]   #: names set by a section or rule naming this node (not a wildcard)
    ignored_by_rcl: dict[str, Any]  #: name -> the value rcl/rclpy would give instead (type clash), if different


def _node_pattern(key: str) -> re.Pattern[str]:
    name = key if key.startswith('/') else '/' + key
    return re.compile(name.replace('/*', r'(/\w+)'))


def _same(a: Any, b: Any) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def _rule_value(text: str, where: str) -> Any:
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as err:
        raise ConfigError(where, f'not a valid value: {yaml_error_text(err)}') from None
    if node is None:
        raise ConfigError(where, 'has no value')
    if isinstance(node, yaml.MappingNode):
        raise ConfigError(where, 'must be a value or a list of values, not a mapping')
    return _rcl_value(node, where)


#: options of ``--ros-args`` that take one argument (skipped); the others are flags
_ROS_OPTIONS_WITH_ARGUMENT = frozenset(('--log-level', '--log-config-file', '--log-file-name', '--enclave', '-e'))


def command_line_parameters(argv: Sequence[str], node_name: str, namespace: str = '/', *,
                            read_file: Any = None) -> CommandLineParameters:
    """The parameters node ``node_name`` gets from the ROS arguments of ``argv`` (``--params-file F``, ``-p
    [node:]name:=value``; ``-r __node:=`` and ``-r __ns:=`` rename it), resolved as rcl and rclpy do, plus the
    value the user wrote last for each name.

    rcl merges every file and rule, in command-line order, into sections keyed by node name (``/**``, ``/*``,
    ``node``, ``/ns/node``, ...; a ``-p`` rule goes to ``/**`` or to its ``node:`` prefix); within a section a
    later value of the same type replaces an earlier one, a value of another type is kept beside it and rclpy reads
    the first type set (bool, integer, double, string, arrays). rclpy then applies the sections matching the node,
    in the order they first appeared. :attr:`CommandLineParameters.ignored_by_rcl` lists the names where the value
    written last is not the one rclpy would give.

    Raises:
        ConfigError: an unreadable file or a value rcl would refuse, naming it.
    """
    read = read_file or (lambda path: Path(path).read_text(encoding='utf-8'))
    sections: dict[str, dict[str, _Variant]] = {}
    name, ns = node_name, namespace
    renamed = False
    args = list(argv)
    in_ros = False
    i = 0
    while i < len(args):
        arg = args[i]
        if arg == '--ros-args':
            in_ros = True
        elif arg == '--' and in_ros:
            in_ros = False
        elif in_ros and arg in ('-p', '--param') and i + 1 < len(args):
            i += 1
            rule = args[i]
            left, sep, text = rule.partition(':=')
            if not sep:
                raise ConfigError(rule, 'a parameter rule is -p name:=value')
            target, colon, pname = left.rpartition(':')
            key = target if colon else '/**'
            where = f'-p {rule}'
            sections.setdefault(key, {}).setdefault(pname, _Variant()).write(_rule_value(text, where), where)
        elif in_ros and arg == '--params-file' and i + 1 < len(args):
            i += 1
            path = args[i]
            try:
                text = read(path)
            except OSError as err:
                raise ConfigFileError(path, f'cannot read: {err.strerror}') from None
            for key, params in ros_parameter_sections(text, path):
                section = sections.setdefault(key, {})
                for pname, value in params.items():
                    section.setdefault(pname, _Variant()).write(value, path)
        elif in_ros and arg in ('-r', '--remap') and i + 1 < len(args):
            i += 1
            left, sep, replacement = args[i].partition(':=')
            target, colon, match = left.rpartition(':')
            if sep and (not colon or target == node_name):
                if match == '__node' and not renamed:
                    name, renamed = replacement, True
                elif match == '__ns' and ns == namespace:
                    ns = replacement
        elif in_ros and arg in _ROS_OPTIONS_WITH_ARGUMENT:
            i += 1
        i += 1
    fqn = ns.rstrip('/') + '/' + name
    resolved: dict[str, tuple[_Variant, str]] = {}
    for key, section in sections.items():
        if _node_pattern(key).fullmatch(fqn):
            for pname, variant in section.items():
                resolved[pname] = (variant, key)
    values = {n: v.last for n, (v, _) in resolved.items()}
    sources = {n: v.where for n, (v, _) in resolved.items()}
    specific = frozenset(n for n, (_, key) in resolved.items() if '*' not in key)
    ignored = {n: v.rclpy_value() for n, (v, _) in resolved.items() if not _same(v.last, v.rclpy_value())}
    return CommandLineParameters(fqn, values, sources, specific, ignored)


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
    from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
    from gimbal_friction.estimation.estimator import EstimatorSettings
    from gimbal_friction.feedforward.rule import FeedforwardSettings
    from gimbal_friction.physics.params import parameter_specs

    packaged_axes, flat = _packaged_flat()

    def fields(*classes: Any) -> list[dict[str, Any]]:
        return [{'name': f.name, 'default': flat.get(f.name, f.default), 'unit': f.metadata.get('unit', ''),
                 'description': f.metadata.get('description', '')} for cls in classes for f in dataclasses.fields(cls)]

    axes = [{'name': 'axes', 'default': list(packaged_axes), 'unit': '', 'description': AXES_DESCRIPTION}]
    model = [{'name': f'model.{spec["name"]}', 'default': flat.get(f'model.{spec["name"]}', spec['default']),
              'unit': spec.get('unit', ''), 'description': spec.get('description', '')} for spec in parameter_specs()]
    model.append({'name': 'axis.<joint>.<field>', 'default': None, 'unit': '', 'description': 'override of '
                  'model.<field> for one joint of axes (unset unless given)'})
    if node == 'friction_feedforward':
        return axes + model + fields(FeedforwardSettings, FeedforwardNodeSettings)
    if node == 'friction_estimator':
        return axes + model + fields(EstimatorSettings, EstimatorNodeSettings)
    if node == 'residual_logger':
        return axes + fields(LoggerSettings)
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
        owners = [other for other, names in others.items() if name in names]
        if owners and name not in specific:
            continue
        if owners:
            raise ConfigError(name, f'is a parameter of {", ".join(owners)}, not of {node}{origin}', values[name])
        parts = name.split('.')
        if parts[0] == 'axis' and len(parts) == 3 and parts[2] in MODEL_PARAMETERS:
            rule = f'joint {parts[1]!r} is not configured (axes: {", ".join(axes)}): add it to axes{origin}'
            raise ConfigError(name, rule, values[name])
        close = difflib.get_close_matches(name, sorted(everything), n=1, cutoff=0.75)
        hint = f' (did you mean {close[0]!r}?)' if close else ''
        raise ConfigError(name, f'unknown parameter{hint}{origin}', values[name])
