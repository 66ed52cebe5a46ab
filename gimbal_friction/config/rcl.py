"""What a ROS node gets from its command line, resolved as rcl and rclpy do (one job: a faithful copy of rcl's
parameter-file and ``-p`` rules, so that a node can tell what the user asked for), and YAML errors as one line.
Used by :mod:`gimbal_friction.config.loader` (which re-exports these names) and the nodes.

A parameter file is untrusted input, read within bounds before rcl sees it (:func:`read_parameter_file`): a regular
file (a FIFO or a device is refused at once, never waited on), at most :data:`MAX_PARAMETER_FILE_BYTES`, UTF-8; its
YAML nested at most :data:`MAX_PARAMETER_DEPTH` deep and without aliases (rcl refuses them too). A refusal is one
line naming the file, never a traceback.
"""

from __future__ import annotations

import ctypes
import math
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from gimbal_friction.common.errors import ConfigError, ConfigFileError
from gimbal_friction.common.files import ReadError, read_text_bounded

#: largest parameter file read [bytes] (the packaged one is 10 kB; a whole robot's file is rarely 100 kB)
MAX_PARAMETER_FILE_BYTES = 4 * 1024 * 1024
#: deepest YAML nesting of a parameter file read (namespaces, node, ros__parameters, parameter groups)
MAX_PARAMETER_DEPTH = 64


def read_parameter_file(path: str | Path) -> str:
    """The text of the parameter file ``path``, read as untrusted input (see the module notes).

    Raises:
        ConfigFileError: one line naming the file: missing, unreadable, a symbolic link loop, not a regular file,
            too big or not UTF-8.
    """
    try:
        return read_text_bounded(path, MAX_PARAMETER_FILE_BYTES, 'a parameter file')
    except ReadError as err:
        rule = {'too_big': f'{err}; name a parameter file', 'not_utf8': f'not a parameter file: {err}'}.get(
            err.kind, f'cannot read: {err}')
        raise ConfigFileError(str(path), rule) from None


def check_parameter_yaml(text: str, source: str) -> None:
    """Refuse YAML that rcl would refuse or that could hang the reader, before it is composed: nesting deeper than
    :data:`MAX_PARAMETER_DEPTH` (the composer recurses) and aliases (rcl: "Will not support aliasing"; an alias can
    also multiply what is built). A syntax error is left to the composer, which words it.

    Raises:
        ConfigFileError: one line naming ``source`` and the line.
    """
    depth = 0
    try:
        for event in yaml.parse(text, Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader)):
            if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                depth += 1
                if depth > MAX_PARAMETER_DEPTH:
                    raise ConfigFileError(source, f'YAML nested more than {MAX_PARAMETER_DEPTH} deep at line '
                                          f'{event.start_mark.line + 1}; not a parameter file')
            elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                depth -= 1
            elif isinstance(event, yaml.AliasEvent):
                raise ConfigFileError(source, f'a YAML alias (*{event.anchor}) at line {event.start_mark.line + 1}: '
                                      'rcl does not support aliasing; write the value out')
    except yaml.YAMLError:
        return


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
    check_parameter_yaml(text, source)
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
    read = read_file or read_parameter_file
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
