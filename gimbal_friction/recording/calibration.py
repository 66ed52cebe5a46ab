"""Calibration of K_T and I_0 (paper Eq. 23) from data, and its result as data: calibrate-kt's library.

- **Input** (:func:`read_input`): a CSV file with a header row and columns ``current_a`` [A], ``torque_nm`` [N*m]
  and optionally ``speed_rad_s`` [rad/s] (``#`` comment lines), or a rosbag2 bag (directory or ``.mcap``) with
  ``/gimbal/calibration/current`` and ``/gimbal/calibration/torque`` (``sensor_msgs/msg/JointState`` effort of the
  axis joint, or ``std_msgs/msg/Float64``), paired by nearest stamp.
- **The run** (:func:`calibrate`): read, fit (:func:`~gimbal_friction.estimation.kt.fit_kt`), check the values
  against the model's parameter rules.
- **The result as data** (:func:`calibration_record`, :func:`calibration_section_text`, :func:`read_calibration`):
  calibrate-kt's parameter file carries, besides its ``/**`` ROS parameters, a section
  ``gimbal_friction_calibration: ros__parameters: {format_version: 1, axis, K_T, I_0, T_0, their 1-sigma, n, R^2,
  date, ...}``. To ROS it is the parameters of a node of that name, which does not exist: the nodes, the config
  loader and ``--params-file`` ignore it, so the file stays layerable. ``refit --calibration`` reads it with a
  version check; a file from before the section (comment header only) is still read, with a note.

>>> rec = {'format_version': 1, 'axis': 'elevation', 'no_load_torque_se_nm': 8.5e-05}
>>> read_calibration_text(calibration_section_text(rec), 'kt.yaml')
CalibrationFile(axis='elevation', no_load_torque_se_nm=8.5e-05, note=None)
"""

from __future__ import annotations

import _csv
import csv
import datetime as dt
import math
import re
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml
from numpy.typing import NDArray

from gimbal_friction.common.errors import ConfigError, ConfigFileError, FitError
from gimbal_friction.estimation.kt import KtFit, fit_kt
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.inputs import index_joints

CURRENT_COLUMN = 'current_a'
TORQUE_COLUMN = 'torque_nm'
SPEED_COLUMN = 'speed_rad_s'
REQUIRED_COLUMNS = (CURRENT_COLUMN, TORQUE_COLUMN)

#: bag topics of a calibration run
CURRENT_TOPIC = '/gimbal/calibration/current'
TORQUE_TOPIC = '/gimbal/calibration/torque'
JOINT_STATE_TYPE = 'sensor_msgs/msg/JointState'
FLOAT64_TYPE = 'std_msgs/msg/Float64'
#: largest stamp difference of a (torque, current) pair read from a bag [s]
DEFAULT_MAX_DT_S = 0.05


class CalibrationData(NamedTuple):
    """Calibration points read from a file: current [A], torque [N*m], optional speed [rad/s], provenance."""

    current_a: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    speed_rad_s: NDArray[np.float64] | None
    rows: list[int]          # CSV line number (or 1-based pair index for a bag) of every point
    kind: str                # 'csv' or 'bag'

#: the section of calibrate-kt's parameter file that carries the result as data, and its format version
CALIBRATION_SECTION = 'gimbal_friction_calibration'
CALIBRATION_FORMAT_VERSION = 1


def _is_bag(path: Path) -> bool:
    return path.is_dir() or path.suffix in ('.mcap', '.db3')


def read_csv(path: Path) -> CalibrationData:
    """Read a calibration CSV (header row; ``#`` comment lines and blank lines skipped).

    Raises:
        FitError: unreadable file, missing column (named), or a non-numeric cell (row and column named).
    """
    try:
        with path.open(newline='', encoding='utf-8-sig') as f:
            return _parse_csv(path, csv.reader(f))
    except OSError as err:
        msg = f'{path}: cannot read: {err.strerror}'
        raise FitError(msg) from None
    except (csv.Error, UnicodeDecodeError) as err:
        msg = f'{path}: not a readable CSV file: {err}'
        raise FitError(msg) from None


def _parse_csv(path: Path, reader: _csv.Reader) -> CalibrationData:
    header: list[str] | None = None
    for row in reader:
        if row and not row[0].lstrip().startswith('#') and any(c.strip() for c in row):
            header = [c.strip() for c in row]
            break
    if header is None:
        msg = f'{path}: empty file: expected a header row {",".join(REQUIRED_COLUMNS)}'
        raise FitError(msg)
    for col in REQUIRED_COLUMNS:
        if col not in header:
            msg = f'{path}: missing column {col!r} (header: {", ".join(header)})'
            raise FitError(msg)
    wanted = [c for c in (*REQUIRED_COLUMNS, SPEED_COLUMN) if c in header]
    for col in wanted:
        if header.count(col) > 1:
            msg = f'{path}: column {col!r} appears more than once in the header'
            raise FitError(msg)
    index = {c: header.index(c) for c in wanted}
    values: dict[str, list[float]] = {c: [] for c in wanted}
    lines: list[int] = []
    data_row = 0
    for row in reader:
        if not row or not any(c.strip() for c in row) or row[0].lstrip().startswith('#'):
            continue
        data_row += 1
        where = f'{path}: row {data_row} (line {reader.line_num})'
        for col, i in index.items():
            if i >= len(row) or not row[i].strip():
                msg = f'{where}, column {col!r}: empty cell'
                raise FitError(msg)
            cell = row[i].strip()
            try:
                values[col].append(float(cell))
            except ValueError:
                msg = f'{where}, column {col!r}: {cell!r} is not a number'
                raise FitError(msg) from None
        lines.append(reader.line_num)
    speed = np.asarray(values[SPEED_COLUMN]) if SPEED_COLUMN in values else None
    return CalibrationData(np.asarray(values[CURRENT_COLUMN]), np.asarray(values[TORQUE_COLUMN]), speed, lines,
                           'csv')


def read_bag(path: Path, axis: str, max_dt_s: float = DEFAULT_MAX_DT_S) -> CalibrationData:
    """Read calibration pairs from a bag: each torque sample with the nearest current sample within ``max_dt_s``.

    Stamps are the header stamps when both topics are ``JointState``, else the log times. Speed is the
    ``velocity`` of the current ``JointState`` when every paired sample has one.

    Raises:
        FitError: unreadable bag, missing topic, unsupported message type, or no pairs.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    series: dict[str, tuple[list[float], list[float], list[float], list[float]]] = {}
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            conns = {c.topic: c for c in reader.connections}
            missing = [t for t in (CURRENT_TOPIC, TORQUE_TOPIC) if t not in conns]
            if missing:
                msg = (f'{path}: bag has no topic {", ".join(missing)} (topics: '
                       f'{", ".join(sorted(conns)) or "none"})')
                raise FitError(msg)
            for topic in (CURRENT_TOPIC, TORQUE_TOPIC):
                if conns[topic].msgtype not in (JOINT_STATE_TYPE, FLOAT64_TYPE):
                    msg = (f'{path}: topic {topic} has type {conns[topic].msgtype}, expected {JOINT_STATE_TYPE} '
                           f'or {FLOAT64_TYPE}')
                    raise FitError(msg)
                series[topic] = ([], [], [], [])
            for conn, log_ns, raw in reader.messages(connections=[conns[CURRENT_TOPIC], conns[TORQUE_TOPIC]]):
                msg_obj = reader.deserialize(raw, conn.msgtype)
                _append_sample(series[conn.topic], msg_obj, conn.msgtype, axis, log_ns)
            header_stamps = all(conns[t].msgtype == JOINT_STATE_TYPE for t in (CURRENT_TOPIC, TORQUE_TOPIC))
    except FitError:
        raise
    except Exception as err:  # rosbags raises several unrelated types (AnyReaderError, ReaderError, OSError)
        msg = f'{path}: cannot read bag: {err}'
        raise FitError(msg) from None
    c_stamp, c_log, c_val, c_vel = (np.asarray(v) for v in series[CURRENT_TOPIC])
    t_stamp, t_log, t_val, _ = (np.asarray(v) for v in series[TORQUE_TOPIC])
    if c_val.size == 0 or t_val.size == 0:
        msg = f'{path}: no samples for joint {axis!r} on {CURRENT_TOPIC} and {TORQUE_TOPIC}'
        raise FitError(msg)
    ct, tt = (c_stamp, t_stamp) if header_stamps else (c_log, t_log)
    order = np.argsort(ct, kind='stable')
    ct, c_val, c_vel = ct[order], c_val[order], c_vel[order]
    j = np.clip(np.searchsorted(ct, tt), 1, max(ct.size - 1, 1))
    left = np.clip(j - 1, 0, ct.size - 1)
    right = np.clip(j, 0, ct.size - 1)
    nearest = np.where(np.abs(ct[left] - tt) <= np.abs(ct[right] - tt), left, right)
    ok = np.abs(ct[nearest] - tt) <= max_dt_s
    if not ok.any():
        msg = f'{path}: no torque sample has a current sample within {max_dt_s:g} s'
        raise FitError(msg)
    idx = nearest[ok]
    vel = c_vel[idx]
    speed = vel if np.all(np.isfinite(vel)) else None
    return CalibrationData(c_val[idx], t_val[ok], speed, list(range(1, int(ok.sum()) + 1)), 'bag')


def _append_sample(store: tuple[list[float], list[float], list[float], list[float]],
                   msg: Any, msgtype: str,  # noqa: ANN401  # a message of the rosbags type store (no stubs)
                   axis: str, log_ns: int) -> None:
    stamps, logs, values, vels = store
    if msgtype == FLOAT64_TYPE:
        stamps.append(log_ns * 1e-9)
        logs.append(log_ns * 1e-9)
        values.append(float(msg.data))
        vels.append(float('nan'))
        return
    i = index_joints(list(msg.name), (), (axis,)).position.get(axis)
    if i is None:
        if len(msg.effort) != 1:
            return
        i = 0   # a one-joint current message under another name
    if i >= len(msg.effort):
        return
    stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
    logs.append(log_ns * 1e-9)
    values.append(float(msg.effort[i]))
    vels.append(float(msg.velocity[i]) if i < len(msg.velocity) else float('nan'))


def read_input(source: Path, axis: str, max_dt_s: float = DEFAULT_MAX_DT_S) -> CalibrationData:
    """Calibration points from a CSV file or a bag (:func:`read_csv`, :func:`read_bag`)."""
    return read_bag(source, axis, max_dt_s) if _is_bag(source) else read_csv(source)


# ---------------------------------------------------------------------------------------------- the run
class Calibration(NamedTuple):
    """A calibrate-kt run: the axis, the input, its points, the fit and the parameter values to write."""

    axis: str
    source: Path
    data: CalibrationData
    fit: KtFit
    values: dict[str, float]   #: torque_constant_nm_per_a [N*m/A], no_load_current_a [A]


def calibrate(source: Path, axis: str, base: AxisParams, max_dt_s: float = DEFAULT_MAX_DT_S) -> Calibration:
    """Read ``source``, fit K_T and I_0 (Eq. 23) and check them against the parameter rules over ``base``.

    Raises:
        FitError: no input, unreadable input, a refused fit, or fitted values outside the allowed range.
        ConfigError: ``max_dt_s`` not > 0.
    """
    if not source.exists():
        msg = f'{source}: no such file or bag'
        raise FitError(msg)
    if not max_dt_s > 0.0:
        raise ConfigError('--max-dt', 'must be > 0 [s]', max_dt_s)
    data = read_input(source, axis, max_dt_s)
    try:
        fit = fit_kt(data.current_a, data.torque_nm, data.speed_rad_s)
    except FitError as err:
        msg = f'{source}: {err}'
        raise FitError(msg) from None
    values = {'torque_constant_nm_per_a': fit.K_T, 'no_load_current_a': fit.I_0}
    try:
        AxisParams.from_mapping(values, base=base)
    except ConfigError as err:
        msg = f'{source}: fitted value outside the allowed range: {err}'
        raise FitError(msg) from None
    return Calibration(axis, source, data, fit, values)


# ---------------------------------------------------------------------------------------------- the result as data
def calibration_record(cal: Calibration, date: str | None = None) -> dict[str, Any]:
    """The result as the ``gimbal_friction_calibration`` section's parameters (format version 1; SI units, 1-sigma
    standard errors; ``date`` ISO 8601 UTC, default now)."""
    fit = cal.fit
    when = date or dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat()
    return {
        'format_version': CALIBRATION_FORMAT_VERSION,
        'axis': cal.axis,
        'torque_constant_nm_per_a': float(fit.K_T),
        'torque_constant_se_nm_per_a': float(fit.se_K_T),
        'no_load_current_a': float(fit.I_0),
        'no_load_current_se_a': float(fit.se_I_0),
        'no_load_torque_nm': float(fit.T_0),
        'no_load_torque_se_nm': float(fit.se_T_0),
        'samples': int(fit.n),
        'samples_used': int(fit.n_inliers),
        'r2': float(fit.r2),
        'residual_std_nm': float(fit.residual_std),
        'date': when,
        'source': str(cal.source.resolve()),
    }


#: strings written unquoted (names); others (a date, a path) are quoted so that rcl reads them as strings
_PLAIN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')
_RCL_WORDS = frozenset(('y', 'n', 'yes', 'no', 'true', 'false', 'on', 'off', 'nan', 'inf'))


def calibration_section_text(record: dict[str, Any]) -> str:
    """The ``gimbal_friction_calibration`` section as YAML (floats with a decimal point, strings quoted, so rcl
    types them as ROS does)."""
    body = {k: (float(repr(v)) if isinstance(v, float) and math.isfinite(v) else v) for k, v in record.items()}
    dumper: Any = type('Dumper', (yaml.SafeDumper,), {})
    dumper.add_representer(str, lambda d, x: d.represent_scalar(
        'tag:yaml.org,2002:str', x, style=None if _PLAIN.fullmatch(x) and x.lower() not in _RCL_WORDS else "'"))
    text: str = yaml.dump({CALIBRATION_SECTION: {'ros__parameters': body}}, Dumper=dumper, sort_keys=False,
                          default_flow_style=False)
    return text


class CalibrationFile(NamedTuple):
    """What ``refit`` needs of a calibrate-kt file: the axis (None: not said), the 1-sigma of T_0 [N*m] and a note
    (None, or one line on an old file read from its comments)."""

    axis: str | None
    no_load_torque_se_nm: float
    note: str | None


_T0_LINE = re.compile(r'T_0 = (\S+) \+/- (\S+) N\*m')
_AXIS_LINE = re.compile(r"no-load current of axis '([^']+)'")


def read_calibration(path: Path) -> CalibrationFile:
    """The calibration result of a calibrate-kt output file (:func:`read_calibration_text`).

    Raises:
        ConfigFileError: not readable, not a calibrate-kt file, an unknown format version or a bad value.
    """
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as err:
        raise ConfigFileError(str(path), f'cannot read: {err.strerror}') from None
    return read_calibration_text(text, str(path))


def read_calibration_text(text: str, source: str) -> CalibrationFile:
    """:func:`read_calibration` of a file's text: its ``gimbal_friction_calibration`` section (format version 1),
    or, for a file written before the section, its comment line ``T_0 = ... +/- SE N*m`` (with a note)."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        doc = None
    section = doc.get(CALIBRATION_SECTION) if isinstance(doc, dict) else None
    if section is not None:
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ConfigFileError(source, f'{CALIBRATION_SECTION} must hold a ros__parameters mapping')
        version = params.get('format_version')
        if version != CALIBRATION_FORMAT_VERSION:
            raise ConfigFileError(source, f'{CALIBRATION_SECTION} format_version {version!r} is not supported '
                                  f'(this version reads {CALIBRATION_FORMAT_VERSION}); rerun calibrate-kt or '
                                  'upgrade gimbal_friction')
        axis = params.get('axis')
        return CalibrationFile(axis if isinstance(axis, str) else None,
                               _se(params.get('no_load_torque_se_nm'), source), None)
    m = _T0_LINE.search(text)
    if m is None:
        raise ConfigFileError(source, f"no {CALIBRATION_SECTION} section and no 'T_0 = ... +/- ... N*m' header "
                              'line: not a calibrate-kt output file')
    a = _AXIS_LINE.search(text)
    note = (f'{source}: a calibrate-kt file without the {CALIBRATION_SECTION} section (written before format '
            'version 1): T_0 uncertainty read from its comment header; rerun calibrate-kt to update it')
    return CalibrationFile(a.group(1) if a else None, _se(m.group(2), source), note)


def _se(value: object, source: str) -> float:
    if not isinstance(value, (str, int, float)):
        raise ConfigFileError(source, f'unreadable T_0 uncertainty {value!r}')
    try:
        se = float(value)
    except ValueError:
        raise ConfigFileError(source, f'unreadable T_0 uncertainty {value!r}') from None
    if not (math.isfinite(se) and se >= 0.0):
        raise ConfigFileError(source, 'the T_0 uncertainty must be a finite value >= 0')
    return se
