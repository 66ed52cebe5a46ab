"""Files that stall or fool a reader (issue 31 items 6, 8 and 9): a correction file is parsed within the shape its
writer produces, so a hostile one is refused at its first entry too many, in one line; a symbolic link loop is not
"no file yet"; a file cut just before its sha256 line says it may be cut; a --params-file is a small regular UTF-8
file read without blocking. Each case fails on the version before this one (a hang, a traceback, a silent
acceptance or another reason)."""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

from gimbal_friction.common.errors import ConfigFileError
from gimbal_friction.config.rcl import MAX_PARAMETER_FILE_BYTES, command_line_parameters
from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionError,
    CorrectionKeeper,
    CorrectionSettings,
    LearningSettings,
    load,
    load_file,
    save,
)
from gimbal_friction.feedforward.correction import file as cfile
from gimbal_friction.physics.params import AxisParams

from .test_files_correction import IDENT, OPEN, refused


def learned(n: int = 3000, seed: int = 0, spread: float = 0.1) -> Correction:
    """A correction with values at -40 degC (positions over ``spread`` rad: more rows)."""
    rng = np.random.default_rng(seed)
    c = Correction(OPEN, IDENT)
    c.learn_residuals('elevation', rng.uniform(-42.0, -38.0, n), v := rng.choice([-0.03, 0.03], n),
                      rng.uniform(-spread, spread, n), 2e-4 * np.sign(v) + 1e-5 * rng.normal(size=n),
                      np.full(n, 3e-3))
    c.settle()
    return c


@pytest.fixture
def good(tmp_path: Path) -> Path:
    path = tmp_path / 'correction.yaml'
    save(learned(), path)
    return path


def resealed(path: Path, body: str) -> None:
    """``path`` holding ``body`` (the YAML after the header) with a matching sha256 line: a hostile file that
    passes the hash."""
    digest = hashlib.sha256(body.encode('utf-8')).hexdigest()
    path.write_text(cfile.HEADER + body + f'sha256: {digest}\n')


def body_of(path: Path) -> str:
    text, _ = cfile._split_digest(path.read_text())
    return cfile._strip_header(text)


# ------------------------------------------------------------------------------------------ item 6: the shape
def test_a_31_mb_periods_list_is_refused_at_its_first_entry_too_many(good: Path) -> None:
    """The issue's file: the valid file with ``periods:`` holding 10.8 million zeros (31 MB, under the 32 MB limit)
    and a recomputed sha256. Refused for the shape before the rest is parsed: the YAML error planted at the end is
    never reached (the reader before parsed it all, for minutes, then refused it on the planted error or with
    "'int' object is not subscriptable")."""
    body = body_of(good).replace('    periods: []\n', '    periods: [' + '0, ' * 10_800_000 + '0]\n')
    assert len(body) > 31_000_000
    resealed(good, body + 'planted: [unclosed\n')
    assert good.stat().st_size < cfile.MAX_BYTES
    refused(good, 'joints.elevation.periods holds more than 4 entries', 'ripple_periods_max')


BAD_SHAPES = [
    ('rows longer than the settings allow', lambda b: b.replace('    - direction: cw\n', '    - direction: cw\n'
                                                                 '      octave: [' + '1, ' * 90_000 + '1]\n', 1),
     ('cells.0.octave holds more than 86424 entries',)),
    ('a speed profile longer than speed_bins', lambda b: b.replace('speed_cw_nm: [', 'speed_cw_nm: [0.0, ', 1),
     ('speed_cw_nm holds more than 12 entries',)),
    ('temperature edges beyond the bins', lambda b: b.replace('temperature_edges_c: [',
                                                              'temperature_edges_c: [-67.5, ', 1),
     ('temperature_edges_c holds more than 38 entries',)),
    ('a guard longer than its columns', lambda b: b.replace('guard: [', 'guard: [0.0, ', 1), ('guard holds more',)),
    ('too many joints', lambda b: b.replace('  joints: [elevation]', '  joints: [' + ', '.join(
        f'j{k}' for k in range(100)) + ']'), ('model.joints holds more than 64 entries',)),
    ('a scalar of a megabyte', lambda b: b.replace('format: gimbal_friction/correction',
                                                   'format: ' + 'x' * 1_000_000), ('1000000 characters',)),
    ('an alias', lambda b: b.replace('temperature_unit: degC', 'temperature_unit: &u degC\nextra: *u'),
     ('anchor',)),
    ('a Python tag', lambda b: b.replace('format: gimbal_friction/correction',
                                         'format: !!python/name:os.system gimbal_friction/correction'),
     ('explicit tag',)),
    ('a repeated key', lambda b: b.replace('version: 3\n', 'version: 3\nversion: 3\n'), ("key 'version' repeated",)),
    ('two documents', lambda b: b + '---\nformat: gimbal_friction/correction\n', ('more than one YAML document',)),
]


@pytest.mark.parametrize(('name', 'change', 'words'), BAD_SHAPES, ids=[c[0] for c in BAD_SHAPES])
def test_a_file_not_of_the_writers_shape_is_refused_naming_the_field(good: Path, name, change, words) -> None:
    resealed(good, change(body_of(good)))
    refused(good, *words)


def test_the_bounded_reader_builds_what_pyyaml_builds(good: Path) -> None:
    """The event reader types plain scalars as PyYAML's safe loader does (YAML 1.1), on the writer's output and on
    what a hand edit might write."""
    body = body_of(good)
    assert cfile._parse(body) == yaml.load(body, Loader=yaml.CSafeLoader)  # a safe loader
    edge = ('a: [0, 7, 010, 0x1f, 0b11, -3, +4, 1_000, 1:30, 1.5, -2.0e-05, 1.0e+3, .5, 1_0.5, .inf, -.inf, .nan, '
            "1e5, yes, No, on, ~, null, '', '1.5', \"x\", 2001-12-14, abc, 0o17]\nb:\nc: |\n  text\n")
    ours, theirs = cfile._parse(edge), yaml.safe_load(edge)
    assert len(ours['a']) == len(theirs['a'])
    for x, y in zip(ours['a'], theirs['a'], strict=True):
        assert type(x) is type(y) and (x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))), (x, y)
    assert ours['b'] is None and ours['c'] == 'text\n'


def test_a_large_file_of_the_writers_shape_still_loads_and_a_reader_can_stop_it(tmp_path: Path) -> None:
    """The writer's output loads whatever its size (here some ten thousand rows); ``cancelled`` stops a read."""
    path = tmp_path / 'big.yaml'
    big = learned(n=40_000, spread=2.0)
    save(big, path)
    keys, _ = big.stats('elevation').rows()
    assert keys.size > 5000
    assert load(path).stats('elevation').samples() == 40_000
    calls: list[int] = []
    with pytest.raises(CorrectionError, match='reading it was cancelled'):
        load_file(path, cancelled=lambda: calls.append(1) is None)
    assert len(calls) == 1


def test_nothing_is_written_that_is_too_big_to_read_back(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A correction whose file would pass the reader's size limit is not written (the reader would refuse it at
    the next start, and a refused file is never overwritten): the file there stays."""
    path = tmp_path / 'c.yaml'
    save(learned(), path)
    before = path.read_bytes()
    monkeypatch.setattr(cfile, 'MAX_BYTES', len(before) // 2)
    with pytest.raises(CorrectionError, match=r'not written, \d+ bytes is more than the'):
        save(learned(n=6000), path)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ['c.yaml']


def test_reading_has_no_shared_state_so_threads_may_read_while_one_serves(tmp_path: Path) -> None:
    """What the node needs to load a file set at run time while the old correction keeps serving: reads in threads
    at once give what each gives alone."""
    paths = []
    for k in range(4):
        paths.append(tmp_path / f'c{k}.yaml')
        save(learned(n=2000 + 500 * k, seed=k), paths[-1])
    alone = [load(p).stats('elevation').samples() for p in paths]
    got: dict[int, int] = {}

    def read(k: int) -> None:
        got[k] = load_file(paths[k], model={'elevation': AxisParams()}).correction.stats('elevation').samples()

    threads = [threading.Thread(target=read, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [got[k] for k in range(4)] == alone


# ------------------------------------------------------------------------------------------ item 8: the file part
def test_a_symbolic_link_loop_is_refused_not_taken_for_no_file_yet(tmp_path: Path) -> None:
    a, b = tmp_path / 'a.yaml', tmp_path / 'b.yaml'
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(CorrectionError, match=r'symbolic link loop'):
        cfile.exists(a)
    refused(a, 'symbolic link loop')
    keeper = CorrectionKeeper(IDENT, CorrectionSettings(), LearningSettings())
    keeper.start(str(a))
    assert keeper.load_error is not None and 'symbolic link loop' in keeper.load_error and keeper.loaded_from is None
    keeper.learner.update('elevation', -40.0, 0.03, 0.0, 2e-4, 3e-3, now_s=0.0)
    keeper.dirty = True
    assert not keeper.save(str(a))             # never written over (the link stays what the user made)
    assert a.is_symlink() and 'refused at load' in (keeper.last_save_error or '')
    assert not cfile.exists(tmp_path / 'none.yaml')


def test_a_file_cut_just_before_its_sha256_line_says_it_may_be_cut(good: Path) -> None:
    text = good.read_text()
    good.write_text(text[:text.rindex('sha256: ')])   # a copy or save that stopped at the last line
    note = load_file(good).note or ''
    assert 'cut short just before that last line' in note and 'deliberate' in note
    doc = yaml.safe_load(good.read_text())              # a hand edit by a YAML tool: the writer's header is gone
    good.write_text(yaml.safe_dump(doc, sort_keys=False))
    note = load_file(good).note or ''
    assert 'edited by hand' in note and 'cut' not in note


# ------------------------------------------------------------------------------------------ item 9: --params-file
def _params(path: Path | str) -> None:
    command_line_parameters(['friction_feedforward', '--ros-args', '--params-file', str(path)],
                            'friction_feedforward')


def test_a_parameter_file_is_a_small_regular_utf8_file(tmp_path: Path) -> None:
    binary = tmp_path / 'binary.yaml'
    binary.write_bytes(os.urandom(256) + b'\xff\xfe')
    big = tmp_path / 'big.yaml'
    big.write_text('/**:\n  ros__parameters:\n    x: "' + 'y' * MAX_PARAMETER_FILE_BYTES + '"\n')
    loop = tmp_path / 'loop.yaml'
    loop.symlink_to(tmp_path / 'loop2.yaml')
    (tmp_path / 'loop2.yaml').symlink_to(loop)
    deep = tmp_path / 'deep.yaml'
    deep.write_text('/**:\n  ros__parameters:\n    x: ' + '[' * 5000 + ']' * 5000 + '\n')
    alias = tmp_path / 'alias.yaml'
    alias.write_text('/**:\n  ros__parameters:\n    a: &big [1, 2]\n    b: *big\n')
    cases = {binary: 'not UTF-8 text', big: f'more than the {MAX_PARAMETER_FILE_BYTES}',
             loop: 'symbolic link loop', tmp_path: 'not a regular file', deep: 'nested more than 64 deep',
             alias: 'rcl does not support aliasing'}
    for path, said in cases.items():
        with pytest.raises(ConfigFileError) as info:
            _params(path)
        assert said in str(info.value) and '\n' not in str(info.value), (path, info.value)


def _bounded_child(args: list[str], path: str) -> subprocess.CompletedProcess[str]:
    """A child reading ``path`` as a parameter file, its memory capped (the reader before read /dev/zero until the
    memory ran out) and its time too (it blocked for ever on a FIFO)."""
    def cap() -> None:
        import resource
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
    code = ('import sys\nfrom gimbal_friction.config.rcl import command_line_parameters\n'
            'from gimbal_friction.common.errors import GimbalFrictionError\n'
            f'try:\n    command_line_parameters({args!r} + [{path!r}], "friction_feedforward")\n'
            'except GimbalFrictionError as err:\n    print(err)\n')
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60,
                          preexec_fn=cap, check=False)


def test_a_fifo_or_a_device_as_parameter_file_is_refused_at_once(tmp_path: Path) -> None:
    fifo = tmp_path / 'fifo.yaml'
    os.mkfifo(fifo)
    for path in (str(fifo), '/dev/zero'):
        run = _bounded_child(['friction_feedforward', '--ros-args', '--params-file'], path)
        assert run.returncode == 0 and 'not a regular file' in run.stdout, (path, run.stdout, run.stderr[-300:])


def test_the_nodes_refuse_a_binary_parameter_file_in_one_line(tmp_path: Path) -> None:
    """Through the real executable: one line on stderr, exit 1, no traceback (a 25-line UnicodeDecodeError
    before)."""
    binary = tmp_path / 'binary.yaml'
    binary.write_bytes(b'\x89PNG\r\n\x1a\n' + os.urandom(512))
    fifo = tmp_path / 'fifo.yaml'
    os.mkfifo(fifo)
    exe = Path(sys.executable).parent / 'friction_feedforward'
    cmd = [str(exe)] if exe.exists() else [sys.executable, '-m', 'gimbal_friction.nodes.feedforward']
    env = dict(os.environ, ROS_LOG_DIR=str(tmp_path / 'log'), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    for path, said in ((binary, 'not UTF-8 text'), (fifo, 'not a regular file')):
        run = subprocess.run([*cmd, '--ros-args', '--params-file', str(path)], capture_output=True, text=True,
                             timeout=60, env=env, check=False)
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 1 and len(lines) == 1 and 'Traceback' not in run.stderr, run.stderr[-800:]
        assert lines[0].startswith(f'friction_feedforward: error: parameter file {path}: ') and said in lines[0]
