"""A learned correction applies nothing it cannot tell apart: a temperature bin's cells wait for each other (the
torque independent of the direction is learned from both directions), and a trend with the angle is held to the
travel its bin's data covered (issue 33, items 3 and 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from gimbal_friction.feedforward.correction import CorrectionError, CorrectionSettings, load, save
from gimbal_friction.feedforward.correction.core import Correction, identifiable_bins
from gimbal_friction.feedforward.correction.settings import model_identity

IDENT = model_identity({'elevation': {}})
GUARDED = CorrectionSettings(guard_min_samples=300, guard_block_samples=25)
OPEN = CorrectionSettings(guard_min_samples=0, guard_z=0.0)
MODEL_NM = 1e-3
UNBALANCE_NM = 1.5e-3      # [N*m] the same signed torque whatever the direction (an unbalance)


def feed(c: Correction, rng: np.random.Generator, n: int, direction: float, t_c: float = -40.0,
         travel_rad: tuple[float, float] = (-0.1, 0.1), torque=None) -> None:
    """``n`` residual samples of one direction, learned test-then-train in chunks of 250, refitted after each."""
    for k0 in range(0, n, 250):
        k = min(250, n - k0)
        v = direction * rng.uniform(0.02, 0.1, k)
        p = rng.uniform(*travel_rad, k)
        tau = np.full(k, UNBALANCE_NM) if torque is None else torque(v, p)
        r = tau + rng.normal(0.0, 2e-5, k)
        assert c.learn_residuals('elevation', np.full(k, t_c), v, p, r, np.full(k, MODEL_NM)) == {}
        c.refit('elevation')


def along(c: Correction, t_c: float, v: float) -> float:
    return c.along_nm('elevation', t_c, v, 0.0, MODEL_NM)


def test_a_cell_waits_while_the_other_direction_of_its_bin_waits_for_its_scores():
    rng = np.random.default_rng(3)
    c = Correction(GUARDED, IDENT)
    feed(c, rng, 4000, +1.0)          # cw: judged (scored by far more than 300)
    feed(c, rng, 150, -1.0)           # ccw: measured, not judged yet
    feed(c, rng, 4000, +1.0, t_c=20.0)   # +20 degC: cw only
    c.settle()
    ver = c.verdicts('elevation')
    b40, b20 = 4, 16
    assert ver[0][b40].scored >= 300 and ver[1][b40].scored < 300
    assert not ver[0][b40].applied and 'ccw cell is not judged yet' in ver[0][b40].reason
    # half the unbalance would have been applied as a friction change: nothing is, in either direction
    assert along(c, -40.0, 0.05) == 0.0 and along(c, -40.0, -0.05) == 0.0
    assert not ver[0][b20].applied and 'common speed' in ver[0][b20].reason and along(c, 20.0, 0.05) == 0.0
    # once the other direction is judged the bin is applied, as a torque independent of the direction
    feed(c, rng, 4000, -1.0)
    c.settle()
    ver = c.verdicts('elevation')
    assert ver[0][b40].applied and ver[1][b40].applied
    odd, even = c.split_nm('elevation', -40.0, 0.05, 0.0, MODEL_NM)
    assert even == pytest.approx(UNBALANCE_NM, rel=0.1) and abs(odd) < 0.1 * UNBALANCE_NM
    assert along(c, -40.0, 0.05) == pytest.approx(-along(c, -40.0, -0.05), rel=0.05)


def test_the_rule_needs_both_directions_at_a_common_speed():
    w = np.zeros((2, 4, 5))
    w[0, :, 2] = 50.0
    w[1, 0, 2] = 50.0                 # bin 0: both at octave 2
    w[1, 1, 4] = 50.0                 # bin 1: ccw two octaves faster
    w[1, 2, 3] = 50.0                 # bin 2: ccw one octave faster: the nodes' hats meet at 3 and 2
    w[0, 2, 3] = 0.5                  # (less than a sample: not a common speed)
    samples = np.array([[50.0, 50.0, 50.0, 50.0], [50.0, 50.0, 50.0, 0.0]])
    assert identifiable_bins(samples, w).tolist() == [True, False, False, False]
    w[0, 2, 3] = 1.0
    assert identifiable_bins(samples, w).tolist() == [True, False, True, False]


def _travel_correction() -> Correction:
    """An angle-dependent unbalance learned over -10 deg .. +10 deg at -40 degC, both directions."""
    rng = np.random.default_rng(5)
    c = Correction(OPEN, IDENT)
    travel = (math.radians(-10.0), math.radians(10.0))

    def torque(v, p):
        return 1e-3 * np.sin(p + 0.4)
    for _ in range(4):
        feed(c, rng, 2000, +1.0, travel_rad=travel, torque=torque)
        feed(c, rng, 2000, -1.0, travel_rad=travel, torque=torque)
    c.settle()
    return c


def _expected_inside(c: Correction, angle: float) -> tuple[float, float]:
    """The (odd, even) parts the applied terms give at ``angle`` [rad] at the bin centre: the speed part (at 0 rad,
    where the trend is 0) plus the trend's sin, cos - 1 terms (the lookup before the travel was kept per bin)."""
    odd0, even0 = c.split_nm('elevation', -40.0, 0.05, 0.0, MODEL_NM)
    tr = c.applied('elevation').trend_nm[4]
    sn, cs = math.sin(angle), math.cos(angle) - 1.0
    return odd0 + tr[0] * sn + tr[1] * cs, even0 + tr[2] * sn + tr[3] * cs


def test_a_trend_learned_over_ten_degrees_each_way_is_the_model_at_forty(tmp_path):
    c = _travel_correction()
    tr = c.applied('elevation').trend_nm[4]
    assert abs(tr[2]) > 5e-4                                            # a trend was learned (independent part)
    lo, hi = c.joint('elevation').bin_ranges[4]
    assert lo == pytest.approx(math.radians(-10.0), abs=0.002) and hi == pytest.approx(math.radians(10.0), abs=0.002)
    at0 = c.split_nm('elevation', -40.0, 0.05, 0.0, MODEL_NM)
    for deg in (-9.0, -3.0, 4.0, 9.5):                                   # inside: the trend as before
        got = c.split_nm('elevation', -40.0, 0.05, math.radians(deg), MODEL_NM)
        assert got == pytest.approx(_expected_inside(c, math.radians(deg)), abs=1e-9)
        assert abs(got[1] - at0[1]) > 1e-5
    for deg in (40.0, -40.0, 90.0):                                      # outside: no trend at all
        assert c.split_nm('elevation', -40.0, 0.05, math.radians(deg), MODEL_NM) == pytest.approx(at0, abs=1e-12)
        odd, even = c.split_nm_array('elevation', [-40.0], [0.05], [math.radians(deg)], [MODEL_NM])
        assert (float(odd[0]), float(even[0])) == pytest.approx(at0, abs=1e-12)
    # the file keeps each bin's travel: a round trip gives the same numbers
    path = tmp_path / 'c.yaml'
    save(c, path)
    back = load(path, IDENT)
    for deg in (-9.0, 0.0, 9.5, 11.0, 40.0):
        a = math.radians(deg)
        assert back.split_nm('elevation', -40.0, 0.05, a, MODEL_NM) == c.split_nm('elevation', -40.0, 0.05, a,
                                                                                    MODEL_NM)
    # a file written before the travel was kept per bin is read: the joint's travel holds for every bin
    doc = yaml.safe_load(path.read_text())
    doc.pop('sha256')
    for rec in doc['joints']['elevation']['applied']:
        del rec['angle_range_rad']
    old = tmp_path / 'old.yaml'
    old.write_text(yaml.safe_dump(doc, sort_keys=False))
    legacy = load(old, IDENT)
    assert legacy.joint('elevation').bin_ranges is None
    assert legacy.split_nm('elevation', -40.0, 0.05, math.radians(40.0), MODEL_NM) == pytest.approx(at0, abs=1e-12)
    # ... but a travel given for some applied bins only, or beyond the joint's, is refused
    recs = doc['joints']['elevation']['applied']
    recs[0]['angle_range_rad'] = [-0.2, 0.2]
    old.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(CorrectionError, match='angle_range_rad'):
        load(old, IDENT)
