"""``synth-bag``'s run as a library function: generate a synthetic chamber test (:mod:`~gimbal_friction.chamber.
synth`) and write it as a rosbag2 bag, atomically (:func:`synth_bag`), with its truth as a parameter file.

The bag is written into a temporary directory next to ``out`` and renamed into place when complete
(:func:`~gimbal_friction.common.files.staged`), so a failed or interrupted run leaves nothing at ``out``. An
existing non-empty ``out`` is refused unless ``force``, and even then only an existing rosbag2 bag directory (one
with ``metadata.yaml``) is replaced.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

from gimbal_friction.chamber.synth import SynthConfig, SynthData, generate, messages, truth_summary
from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.files import os_error_text, staged, write_text_atomic
from gimbal_friction.config.loader import render_parameter_file
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.errors import RecordingError

STORAGES = ('mcap', 'sqlite3')
COMPRESSIONS = ('none', 'zstd')
#: progress callback: (done, total, label)
Progress = Callable[[int, int, str], None]


class SynthBag(NamedTuple):
    """A synth-bag run: the data generated and the JSON summary (``doc``: paths, counts, size, timings, truth)."""

    data: SynthData
    doc: dict[str, Any]


def synth_bag(cfg: SynthConfig, out: Path, *, storage: str = 'mcap', compression: str | None = None,
              force: bool = False, truth_out: Path | None = None, progress: Progress | None = None) -> SynthBag:
    """Generate the test of ``cfg`` and write it as the bag ``out`` (``compression`` None: zstd for mcap, none for
    sqlite3) and, with ``truth_out``, its truth as a parameter file.

    Raises:
        RecordingError: ``out`` or ``truth_out`` must not be replaced, or the bag cannot be written.
        ConfigError: an unknown storage or compression.
    """
    replace = check_out(out, force)
    if truth_out is not None and truth_out.exists() and not force:
        raise RecordingError(f'{truth_out}: exists; nothing written (use --force to replace it)')
    if storage not in STORAGES:
        raise ConfigError('--storage', f'must be one of {", ".join(STORAGES)}', storage)
    chosen = compression or ('zstd' if storage == 'mcap' else 'none')
    if chosen == 'zstd' and storage != 'mcap':
        raise ConfigError('--compression', 'zstd is only offered with mcap storage', chosen)
    t0 = time.perf_counter()
    data = generate(cfg)
    t1 = time.perf_counter()
    size = write_bag(data, out, storage=storage, compression=chosen, replace=replace, progress=progress)
    t2 = time.perf_counter()
    if truth_out is not None:
        write_text_atomic(truth_out, truth_parameter_text(cfg))
    counts = data.message_counts()
    doc = {
        'out': str(out), 'storage': storage, 'compression': chosen, 'seed': cfg.seed,
        'joints': list(cfg.joints),
        'duration_s': data.duration_s, 'start_ns': cfg.start_ns, 'messages': counts,
        'total_messages': sum(counts.values()), 'size_bytes': size,
        'generate_s': t1 - t0, 'write_s': t2 - t1,
        'plateaus': [p.records(cfg.start_ns) for p in data.plateaus],
        'truth': truth_summary(cfg), 'truth_out': None if truth_out is None else str(truth_out),
        'config': config_record(cfg),
    }
    return SynthBag(data, doc)


def check_out(out: Path, force: bool) -> bool:
    """True when ``out`` exists and will be replaced. Raises when it must not be touched."""
    if not out.exists() and not out.is_symlink():
        return False
    if not out.is_dir() or out.is_symlink():
        raise RecordingError(f'{out}: exists and is not a directory; refusing to overwrite it')
    if not any(out.iterdir()):
        return True
    if not force:
        raise RecordingError(f'{out}: directory exists and is not empty; nothing written (use --force to '
                             'replace an existing bag)')
    if not (out / 'metadata.yaml').is_file():
        raise RecordingError(f'{out}: not a rosbag2 bag directory (no metadata.yaml); refusing to delete it '
                             'even with --force')
    return True


def _dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob('*') if p.is_file())


def _with_progress(items: Iterator[Any], total: int, progress: Progress | None, every: int = 5000
                   ) -> Iterator[Any]:
    for done, item in enumerate(items, start=1):
        yield item
        if progress is not None and done % every == 0:
            progress(done, total, 'synth-bag: writing')
    if progress is not None:
        progress(total, total, 'synth-bag: writing')


def _write_zstd_mcap(path: Path, items: Iterator[tuple[str, str, int, Any]]) -> None:
    """Like :func:`~gimbal_friction.recording.bag_write.write_chamber_bag` (mcap), with zstd-compressed chunks."""
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
    from rosbags.serde import SerdeError

    from gimbal_friction.recording.bag import default_typestore

    store = default_typestore()
    connections: dict[str, Any] = {}
    try:
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with writer:
            for topic, msgtype, log_time_ns, message in items:
                conn = connections.get(topic)
                if conn is None:
                    conn = connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
                writer.write(conn, int(log_time_ns), store.serialize_cdr(message, msgtype))
    except (WriterError, SerdeError, KeyError) as err:
        raise RecordingError(f'writing bag {path}: {err}') from err


def write_bag(data: SynthData, out: Path, *, storage: str = 'mcap', compression: str = 'none',
              replace: bool = False, progress: Progress | None = None) -> int:
    """Write ``data`` as a bag directory at ``out`` atomically (temporary sibling, then rename); size [bytes]."""
    from gimbal_friction.recording.bag_write import write_chamber_bag

    if compression not in COMPRESSIONS:
        raise ConfigError('--compression', f'must be one of {", ".join(COMPRESSIONS)}', compression)
    if compression == 'zstd' and storage != 'mcap':
        raise ConfigError('--compression', 'zstd is only offered with mcap storage', compression)
    total = sum(data.message_counts().values())
    try:
        with staged(out, replace=replace, what='bag', error=RecordingError) as folder:
            items = _with_progress(messages(data), total, progress)
            if compression == 'zstd':
                _write_zstd_mcap(folder, items)
            else:
                write_chamber_bag(folder, items, storage=storage)
    except OSError as err:
        raise RecordingError(f'{out}: cannot write the bag: {os_error_text(err)}') from None
    return _dir_size(out)


def truth_parameter_text(cfg: SynthConfig) -> str:
    """The truth as a parameter file: ``model.*`` = first joint vs the package defaults, ``axis.<j>.*`` for the
    other joints where they differ from the first, and each joint's motor constants."""
    defaults = AxisParams()
    joints = cfg.joints
    first = _with_motor(cfg, joints[0])
    model = {k: v for k, v in first.to_mapping().items() if v != getattr(defaults, k)}
    axes: dict[str, dict[str, Any]] = {}
    for joint in joints[1:]:
        p = _with_motor(cfg, joint)
        diff = {k: v for k, v in p.to_mapping().items() if v != getattr(first, k)}
        if diff:
            axes[joint] = diff
    legacy = ('the cold direction asymmetry (|CCW|/|CW| = '
              f'{cfg.asym_ratio_cold:.4f} at {cfg.asym_t_cold_c:g} degC, 1 at {cfg.asym_t_ref_c:g} degC and above)\n'
              'and ') if cfg.asym_ratio_cold != 1.0 else ''
    header = (f'Truth of a synthetic chamber bag: gimbal-friction synth-bag --seed {cfg.seed}\n'
              'Layer over the packaged defaults (--config / --params-file) to predict with the truth model.\n'
              f'Not part of the truth here: {legacy}the position ripple.')
    return render_parameter_file(model, axes or None, axes=list(joints), header=header)


def _with_motor(cfg: SynthConfig, joint: str) -> AxisParams:
    kt, i0 = cfg.motor_constants(joint)
    p = cfg.truth_params(joint)
    return dataclasses.replace(p, torque_constant_nm_per_a=kt, no_load_current_a=i0)


def config_record(cfg: SynthConfig) -> dict[str, Any]:
    skip = {'truth_base', 'truth_overrides'}
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cfg):
        if f.name in skip:
            continue
        value = getattr(cfg, f.name)
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out
