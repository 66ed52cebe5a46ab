"""A correction file's figures checked against the model it names (issue 31 item 7): the reader gets the model the
node runs (the file holds only its hash) and refuses a file whose sums claim what that model cannot give, so a file
never moves the output further than the node could have learned to. Versions 1 and 2 too. Each case was accepted
by the version before this one (it pinned the output at the 0.02 N*m clamp)."""

from __future__ import annotations

import copy
import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from gimbal_friction.common.xp import ARRAY
from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionError,
    CorrectionKeeper,
    CorrectionSettings,
    LearningSettings,
    load,
    load_file,
    model_identity,
    save,
)
from gimbal_friction.feedforward.correction import file as cfile
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams

AXIS = AxisParams(direction_asymmetry_cold=0.131, direction_asymmetry_warm=-0.121)   # the paper's CW/CCW means
MODEL = {'elevation': AXIS}
IDENT = model_identity(MODEL)
OPEN = CorrectionSettings(guard_min_samples=0, guard_z=0.0)


def learned_against_the_model(n: int = 8000, seed: int = 0) -> Correction:
    """What the node learns: residuals against its own model friction (the feedforward's table, its direction
    factors) over -45..65 degC (credible temperatures outside the validity range used at its edge), speeds from
    0.006 to 15 rad/s, both directions."""
    rng = np.random.default_rng(seed)
    ff = Feedforward(MODEL, FeedforwardSettings())
    t = rng.uniform(-45.0, 65.0, n)
    v = rng.choice([-1.0, 1.0], n) * np.exp(rng.uniform(np.log(0.006), np.log(15.0), n))
    p = rng.uniform(-0.02, 0.02, n)
    m = np.asarray(ff.model_nm('elevation', v, t, ARRAY))
    c = Correction(OPEN, IDENT)
    c.learn_residuals('elevation', t, v, p, 1e-4 * np.sign(v) + 2e-5 * rng.normal(size=n), m)
    c.settle()
    return c


@pytest.fixture(scope='module')
def good_text(tmp_path_factory: pytest.TempPathFactory) -> str:
    path = tmp_path_factory.mktemp('c') / 'good.yaml'
    save(learned_against_the_model(), path)
    return path.read_text()


def written(path: Path, doc: dict[str, Any], seal: bool = True) -> Path:
    """``doc`` as the writer writes it, with a recomputed sha256 (``seal``): a forgery that passes the hash."""
    body = cfile._dump(doc)
    tail = f'sha256: {hashlib.sha256(body.encode()).hexdigest()}\n' if seal else ''
    path.write_text(cfile.HEADER + body + tail)
    return path


def doc_of(text: str) -> dict[str, Any]:
    body, _ = cfile._split_digest(text)
    return yaml.load(body, Loader=yaml.CSafeLoader)  # a safe loader


def refused_with_the_model(path: Path, *words: str) -> str:
    with pytest.raises(CorrectionError) as err:
        load_file(path, model=MODEL)
    message = str(err.value)
    assert '\n' not in message and message.startswith(f'correction file {path}: '), message
    for w in words:
        assert w in message, message
    return message


def test_what_the_node_learns_against_its_model_loads_with_that_model(tmp_path: Path, good_text: str) -> None:
    path = tmp_path / 'c.yaml'
    path.write_text(good_text)
    c = load_file(path, model=MODEL).correction
    assert c.stats('elevation').samples() == 8000 and len(c.cells('elevation')) > 30
    # learned against another model (another hash): refused as before; the model given must be the file's
    with pytest.raises(CorrectionError, match='learned against model parameters'):
        load_file(path, model={'elevation': AxisParams()})


def test_a_bin_claiming_a_model_of_1_nm_is_refused(tmp_path: Path, good_text: str) -> None:
    """The issue's file: the -40 degC bin claims a mean |model| of 1 N*m (the model gives about 3 mN*m) and holds
    applied values of 3 N*m inside the bound its own sums set; the sha256 recomputed."""
    doc = doc_of(good_text)
    joint = doc['joints']['elevation']
    for cell in joint['cells']:
        if cell['bin'] == 4:
            cell['sum_model_nm'] = [float(n) * 1.0 for n in cell['n']]
    for rec in joint['applied']:
        if rec['bin'] == 4:
            rec['speed_cw_nm'] = [3.0] * len(rec['speed_cw_nm'])
    path = written(tmp_path / 'forged.yaml', doc)
    assert load(path).stats('elevation').samples() == 8000         # the file is consistent with itself ...
    message = refused_with_the_model(path, 'bin 4 (-40 degC)', 'mean |model| of 1 N*m', 'not learned against')
    assert 'N*m over the bin and speed octave' in message             # ... not with the model it names
    # the node's keeper (given its model) and the in-process API refuse it the same way
    keeper = CorrectionKeeper(IDENT, OPEN, LearningSettings(), model=MODEL)
    keeper.start(str(path))
    assert keeper.load_error is not None and 'mean |model|' in keeper.load_error and keeper.loaded_from is None


@pytest.mark.parametrize(('name', 'factor'), [('twice the model', 2.0), ('a tenth of it', 0.1)])
def test_a_model_sum_off_by_a_factor_is_refused(tmp_path: Path, good_text: str, name: str, factor: float) -> None:
    doc = doc_of(good_text)
    cell = doc['joints']['elevation']['cells'][3]
    cell['sum_model_nm'] = [x * factor for x in cell['sum_model_nm']]
    for k, (r, m) in enumerate(zip(cell['sum_nm'], cell['sum_model_nm'], strict=True)):   # (inside the gate)
        cell['sum_nm'][k] = float(np.clip(r, -m, m))
    refused_with_the_model(written(tmp_path / 'c.yaml', doc), 'mean |model|')


@pytest.mark.parametrize(('column', 'value'), [(0, 1e9), (1, 1e6)])
def test_guard_scores_beyond_what_the_cell_learned_are_refused(tmp_path: Path, good_text: str, column: int,
                                                                value: float) -> None:
    """The guard scores samples the cell then learns: never more of them (column n) nor larger squared residuals
    (e_model) than the cell holds."""
    doc = doc_of(good_text)
    doc['joints']['elevation']['cells'][0]['guard'][column] = value
    path = written(tmp_path / 'c.yaml', doc)
    with pytest.raises(CorrectionError, match=r'cells\[0\]\.guard: it scores more samples or larger squared'):
        load(path)


@pytest.mark.parametrize(('name', 'change', 'words'), [
    ('a mean that is not its sums', lambda c: c.update(mean_nm=c['mean_nm'] + 1.0), ('mean_nm', 'not the mean')),
    ('a centre off its bin', lambda c: c.update(centre_c=c['centre_c'] + 1.0), ('centre_c', 'not the centre')),
    ('a level beyond the bound', lambda c: c.update(value_nm=1.0), ('value_nm', 'beyond the bound')),
])
def test_what_a_cell_says_must_follow_from_its_sums(tmp_path: Path, good_text: str, name, change, words) -> None:
    doc = doc_of(good_text)
    change(doc['joints']['elevation']['cells'][2])
    path = written(tmp_path / 'c.yaml', doc)
    with pytest.raises(CorrectionError) as err:
        load(path)
    assert all(w in str(err.value) for w in words), err.value


V2 = {
    'format': 'gimbal_friction/correction', 'version': 2, 'torque_unit': 'N*m', 'temperature_unit': 'degC',
    'position_unit': 'rad', 'model': {'joints': ['elevation'], 'params_sha256': IDENT.params_sha256},
    'settings': {'temperature_min_c': -62.5, 'temperature_max_c': 122.5, 'temperature_bin_c': 5.0,
                 'prior_samples': 20.0, 'max_relative': 0.5, 'floor_nm': 2e-05, 'min_speed_rad_s': 0.005,
                 'speed_reference_rad_s': 0.0349066},
    'temperature_edges_c': [-62.5 + 5.0 * k for k in range(38)],
    'joints': {'elevation': [
        {'direction': 'cw', 'bin': 4, 'samples': 500, 'sum_nm': 0.1, 'sum_abs_model_nm': 1.6, 'sum_speed': 500.0,
         'sum_sq_nm2': 3e-5, 'value_nm': 2e-4, 'speed_nm': 0.0, 'speed_ref': 1.0},
        {'direction': 'ccw', 'bin': 4, 'samples': 400, 'sum_nm': -0.08, 'sum_abs_model_nm': 1.2,
         'sum_speed': 400.0, 'sum_sq_nm2': 2e-5, 'value_nm': -2e-4, 'speed_nm': 0.0, 'speed_ref': 1.0}]},
    'samples_total': {'elevation': 900},
}


def test_version_2_files_are_checked_too(tmp_path: Path) -> None:
    """The issue's two version-2 files loaded with only a "converted" note: a value of 1 N*m, and a sum of |model|
    of 1e14."""
    path = tmp_path / 'v2.yaml'
    path.write_text(yaml.safe_dump(V2, sort_keys=False))
    loaded = load_file(path, model=MODEL)                      # a plausible one loads, converted
    assert loaded.note is not None and 'version-2' in loaded.note
    doc = copy.deepcopy(V2)
    doc['joints']['elevation'][0]['value_nm'] = 1.0
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(CorrectionError, match=r'cells\[0\]\.value_nm = 1\.0 lies beyond the bound'):
        load(path)                                             # refused, even without the model
    doc = copy.deepcopy(V2)
    doc['joints']['elevation'][1]['sum_abs_model_nm'] = 1e14
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    refused_with_the_model(path, 'cell ccw bin 4', 'mean |model| of 2.5e+11 N*m')


def test_the_in_process_api_and_export_check_the_file_against_their_model(tmp_path: Path, good_text: str) -> None:
    from gimbal_friction.cli.main import main
    from gimbal_friction.config.loader import render_parameter_file
    from gimbal_friction.controller import load_feedforward
    config = tmp_path / 'unit.yaml'
    config.write_text(render_parameter_file({'direction_asymmetry_cold': 0.131, 'direction_asymmetry_warm': -0.121}))
    good = tmp_path / 'good.yaml'
    good.write_text(good_text)
    assert load_feedforward(config, correction=good).correction is not None
    doc = doc_of(good_text)
    for cell in doc['joints']['elevation']['cells']:
        cell['sum_model_nm'] = [float(n) * 1.0 for n in cell['n']]
    forged = written(tmp_path / 'forged.yaml', doc)
    with pytest.raises(CorrectionError, match=r'mean \|model\|'):
        load_feedforward(config, correction=forged)
    assert main(['export', '--out', str(tmp_path / 'x'), '--config', str(config), '--correction', str(forged),
                 '--random-points', '200']) == 1
    assert not (tmp_path / 'x').exists()
