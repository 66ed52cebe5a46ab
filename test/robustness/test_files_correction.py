"""A learned correction file is untrusted input (issue 26, items 1-7): what a damaged, hostile or hand-edited file does
to the reader, what absurd samples do to learning, and what an interrupted save leaves behind. Each case fails on
the version before this one (a traceback, a crash, a hang, or silently accepted)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import yaml

from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionError,
    CorrectionKeeper,
    CorrectionSettings,
    Learner,
    LearningSettings,
    load,
    load_file,
    model_identity,
    save,
)
from gimbal_friction.feedforward.correction import file as cfile
from gimbal_friction.physics.params import AxisParams

IDENT = model_identity({'elevation': AxisParams()})
OPEN = CorrectionSettings(guard_min_samples=0, guard_z=0.0)


def learned(n=3000, seed=0) -> Correction:
    """A correction with values in two cells at -40 degC."""
    rng = np.random.default_rng(seed)
    c = Correction(OPEN, IDENT)
    t = rng.uniform(-42.0, -38.0, n)
    v = rng.choice([-0.03, 0.03], n)
    p = rng.uniform(-0.05, 0.1, n)
    c.learn_residuals('elevation', t, v, p, 2e-4 * np.sign(v) + 1e-5 * rng.normal(size=n), np.full(n, 3e-3))
    c.settle()
    return c


@pytest.fixture
def good(tmp_path):
    path = tmp_path / 'correction.yaml'
    save(learned(), path)
    return path


def refused(path, *words):
    with pytest.raises(CorrectionError) as err:
        load(path)
    message = str(err.value)
    assert '\n' not in message and message.startswith(f'correction file {path}: '), message
    for w in words:
        assert w in message, message
    return message


def edited(path, change, keep_sha=False):
    """``path`` with its YAML changed by ``change(doc)``; without its sha256 line (a deliberate edit) unless
    ``keep_sha``."""
    text = path.read_text()
    body, digest = cfile._split_digest(text)   # the format's own split, as a user's edit would
    doc = yaml.safe_load(body)
    change(doc)
    out = yaml.safe_dump(doc, sort_keys=False)
    if keep_sha:
        out += f'sha256: {digest}\n'
    path.write_text(out)


# ------------------------------------------------------------------------------------------------ items 1-4: reading
def test_a_file_that_is_not_utf8_is_refused_in_one_line(tmp_path):
    path = tmp_path / 'c.yaml'
    path.write_bytes(b'\xff\xfe')
    refused(path, 'not UTF-8')


@pytest.mark.parametrize(('field', 'value', 'words'), [
    ('bin', math.inf, ('bin',)),
    ('samples', 1.0e20, ('samples',)),
    ('samples', 240.7, ('samples', 'whole number')),
])
def test_an_infinite_or_absurd_count_is_refused_naming_the_field(good, field, value, words):
    edited(good, lambda d: d['joints']['elevation']['cells'][0].update({field: value}))
    refused(good, *words)


def test_deep_nesting_is_refused_before_it_is_built_and_a_huge_file_before_it_is_read(tmp_path):
    nested = tmp_path / 'nested.yaml'
    nested.write_text('x: ' + '[' * 30000 + ']' * 30000 + '\n')
    # in a child process: the reader of the version before crashed the interpreter here (SIGSEGV)
    code = textwrap.dedent(f"""
        from gimbal_friction.feedforward.correction import CorrectionError, load
        try:
            load({str(nested)!r})
        except CorrectionError as err:
            print(err)
        """)
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0 and 'nested more than' in out.stdout, (out.returncode, out.stdout, out.stderr[-500:])
    huge = tmp_path / 'huge.yaml'
    with huge.open('w') as f:
        f.write('temperature_edges_c: [' + '1.0, ' * (cfile.MAX_BYTES // 5 + 10) + '1.0]\n')
    refused(huge, 'bytes', str(cfile.MAX_BYTES))   # refused on its size, before it is read (parsed for a minute before)


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / 'fifo.yaml'
    os.mkfifo(fifo)
    code = ('from gimbal_friction.feedforward.correction import CorrectionError, load\n'
            f'try:\n    load({str(fifo)!r})\nexcept CorrectionError as err:\n    print(err)\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0 and 'not a regular file' in out.stdout, out.stdout + out.stderr


# ------------------------------------------------------------------------------------------------ item 5: values
@pytest.mark.parametrize(('name', 'change', 'words'), [
    ('value 1.0', lambda d: d['joints']['elevation']['applied'][0].update(speed_cw_nm=[1.0] * 12),
     ('speed_cw_nm', 'outside')),
    ('value 1e308', lambda d: d['joints']['elevation']['applied'][0].update(speed_ccw_nm=[-1e308] * 12),
     ('speed_ccw_nm',)),
    ('negative sum of squares', lambda d: d['joints']['elevation']['cells'][0].update(sum_sq_nm2=-1.0),
     ('sum_sq_nm2',)),
    ('negative model sums', lambda d: d['joints']['elevation']['cells'][0].update(
        sum_model_nm=[-x for x in d['joints']['elevation']['cells'][0]['sum_model_nm']]), ('sum_model_nm',)),
    ('residual sums beyond the gate', lambda d: d['joints']['elevation']['cells'][0].update(
        sum_nm=[1e3 for _ in d['joints']['elevation']['cells'][0]['sum_nm']]), ('sum_nm', 'learning gate')),
    ('fractional count', lambda d: d['joints']['elevation']['cells'][0].update(
        n=[x + 0.7 for x in d['joints']['elevation']['cells'][0]['n']]), ('whole numbers',)),
    ('samples 0 with values', lambda d: d['joints']['elevation']['cells'][0].update(samples=0), ('samples',)),
    ('an applied value without samples', lambda d: d['joints']['elevation']['applied'][0].update(bin=30),
     ('has no samples',)),
    ('a guard count below zero', lambda d: d['joints']['elevation']['cells'][0]['guard'].__setitem__(0, -5.0),
     ('guard',)),
    ('a nan', lambda d: d['joints']['elevation']['cells'][0].update(mean_nm=float('nan'),
                                                                    sum_sq_nm2=float('nan')), ('not finite',)),
])
def test_a_value_the_learner_could_not_have_written_is_refused_naming_the_field(good, name, change, words):
    edited(good, change)
    refused(good, *words)


def test_a_hand_edit_is_refused_unless_deliberate(good):
    def bump(d):
        d['joints']['elevation']['applied'][0]['speed_cw_nm'][3] *= 1.01
    edited(good, bump, keep_sha=True)                 # edited, its sha256 kept: refused
    refused(good, 'sha256 does not match')
    edited(good, lambda d: None)                       # the sha256 line deleted: a deliberate edit, read and said
    loaded = load_file(good)
    assert loaded.note is not None and 'edited by hand' in loaded.note


def test_a_file_cut_short_is_refused(good):
    text = good.read_text()
    good.write_text(text[:len(text) // 2])
    with pytest.raises(CorrectionError):
        load(good)


def test_nothing_is_written_that_would_not_read_back(tmp_path):
    c = learned()
    c.stats('elevation').sums[0, 1] = math.nan        # a state the reader would refuse
    path = tmp_path / 'c.yaml'
    with pytest.raises(CorrectionError, match='not written, it would not read back'):
        save(c, path)
    assert not path.exists()


# ------------------------------------------------------------------------------------------------ item 6: learning
def test_absurd_samples_are_refused_by_the_gate_and_nothing_learned_is_lost(tmp_path):
    c = Correction(CorrectionSettings(), IDENT)
    learner = Learner(c, LearningSettings(max_rate_nm_per_min=1.0, step_period_s=0.1))
    for k in range(2000):
        learner.update('elevation', -40.0, 0.03 if k % 2 else -0.03, 0.0, 2e-4 if k % 2 else -2e-4, 3e-3,
                       now_s=0.01 * k)
    for k in range(2000):   # measured frictions of 1e308, velocities of 1e300 rad/s
        learner.update('elevation', -40.0, 1e300 if k % 3 == 0 else 0.03, 0.0, 1e308 if k % 3 else 2e-4, 3e-3,
                       now_s=20.0 + 0.01 * k)
    learner.step(100.0)
    s = learner.summary()
    assert s['rejected']['implausible friction'] + s['rejected']['implausible speed'] == 2000
    assert all(math.isfinite(s[k]) for k in ('max_abs_correction_nm', 'max_abs_ripple', 'max_abs_unbalance_nm'))
    keys, sums = c.stats('elevation').rows()
    assert np.all(np.isfinite(sums)) and float(np.max(sums[:, 2] / sums[:, 0])) < 1.0
    path = tmp_path / 'c.yaml'
    save(learner.snapshot(), path)
    assert load(path).stats('elevation').samples() == 2000


# ------------------------------------------------------------------------------------------------ item 7: saves
def test_stale_temporaries_of_an_interrupted_save_are_removed_at_start(tmp_path):
    path = tmp_path / 'correction.yaml'
    save(learned(), path)
    stale = [tmp_path / f'.correction.yaml.abc{k}.tmp' for k in range(6)]
    for p in stale:
        p.write_text('half a file')
        os.utime(p, (time.time() - 60.0, time.time() - 60.0))
    other = tmp_path / '.other.yaml.abc.tmp'
    other.write_text('not ours')
    os.utime(other, (time.time() - 60.0, time.time() - 60.0))
    keeper = CorrectionKeeper(IDENT, OPEN, LearningSettings())
    keeper.start(str(path))
    assert keeper.load_error is None and len(keeper.removed_temporaries) == 6
    assert not any(p.exists() for p in stale) and other.exists() and path.exists()
