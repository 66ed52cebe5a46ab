r"""The loop's error judges the learned correction, cell by cell, in service (pure numpy; no rclpy, no I/O).

One job in one module: :class:`LoopJudge` (its cells, its randomised blocks, its contrasts and its verdicts share one
state).

The residual guard (:mod:`~gimbal_friction.feedforward.correction.core`) asks whether a candidate explains the
friction residual better than the model; that is not what a seeker wants. Where friction falls steeply with speed, a
correction that cuts the residual can still make the loop worse. The judge asks the loop instead. This is
unfalsified control (Safonov & Tsao 1997): a candidate stays in use only while the data do not falsify it, and the
plain model is the safe fallback.

- **Cells** are joint × direction × temperature bin of the correction (the layout of its
  :class:`~gimbal_friction.feedforward.correction.settings.CorrectionSettings`). Each cell is ``untested`` (the
  applied correction does not differ from the model there), ``testing``, ``applied`` or ``withdrawn``. Each
  direction is judged on its own, but both directions of a bin are switched together: a bin uses its correction only
  where each direction with a candidate says on (the part independent of the direction, an unbalance, must not
  step at a reversal).
- **Blocks**: time is cut into blocks of ``block_s``. In every group of ``G = round(1/on_share)`` consecutive blocks,
  a cell in test has its candidate on in exactly one block, chosen by a seeded random draw. An applied cell has its
  candidate off in one block of every ``round(1/applied_off_share)``, so later data can still withdraw it. The share
  of blocks on is fixed (not just its expected value), and each group compares blocks close together in time. The
  feedforward asks :meth:`LoopJudge.use_candidate` on every call; this is a lookup in an array that is recomputed once
  per block.
- **Samples**: the loop error (the LOS rate error the controller sees [rad/s]) is summed per block into the cell the
  gimbal was in and its speed octave (matched conditions). The first ``settle_s`` of each block is skipped, because
  the loop is still settling after a switch; a sample counts at most ``error_cap_rad_s`` (a slew's error is the
  reference's, not the friction's, and would drown a block). For each block and speed octave with at least
  ``min_block_samples`` samples, the judge takes x = ln(mean e²).
- **Contrast**: for each complete group, d = mean x(on) − mean x(off), taken per speed octave seen both on and off,
  then weighted over the octaves by their samples, and clipped to ±:data:`D_CLIP` (a slew in one block). Across groups
  the judge tracks the mean of d and its standard error, forgetting over ``memory_groups``. A cell in test is applied
  when z = mean/SE < −``z`` and it has at least ``min_blocks`` blocks each way. It is withdrawn when z > ``stop_z``
  (the candidate makes the loop worse: the test stops early), or when it has shown no gain after ``max_blocks`` blocks
  on. An applied cell is withdrawn when z > ``stop_z``.
- **A new candidate**: :meth:`LoopJudge.offer` or :meth:`LoopJudge.update_candidates` compare a cell's candidate (the
  applied correction along the motion, sampled over speed and angle) with the one its test began on. If it moved by
  more than ``restart_relative`` of its size, the test goes on in one of two ways. A new shape (more than
  ``restart_relative`` of it is no multiple of the old one) restarts the test from nothing. The same shape at another
  size (a learner moving at its limited rate, a refit) keeps its state and its evidence, which counts
  :data:`RESIZE_WEIGHT` from then on (a withdrawn cell is tested again). A cell whose candidate is the model goes back
  to ``untested``.

Everything is bounded: arrays per cell and speed octave, plus the records of the last blocks (one group of the
longest kind).
Everything is reversible: a withdrawn cell is tested again when its candidate changes, and :meth:`LoopJudge.reset`
starts over. :meth:`LoopJudge.summary` and :meth:`LoopJudge.cells` report what the judge has done.

>>> from gimbal_friction.feedforward.correction.settings import CorrectionSettings, JudgeSettings
>>> j = LoopJudge(CorrectionSettings(), ('elevation',), JudgeSettings(block_s=1.0, min_blocks=3))
>>> sig = np.zeros((2, CorrectionSettings().n_temperature, 1)); sig[:, 4] = 1e-4   # a candidate in the -40 degC bin
>>> j.offer('elevation', sig); j.state_of('elevation', -40.0, 0.1)
'testing'
>>> rng = np.random.default_rng(0)
>>> for k in range(40):                      # 40 s: the loop error is 30 % lower while the candidate is on
...     t = k + np.arange(0.0, 1.0, 0.01)
...     on = j.use_candidate('elevation', -40.0, 0.1, float(t[0]))
...     e = (0.7 if on else 1.0) * rng.normal(0.0, 1e-3, t.size)
...     _ = j.observe('elevation', t, np.full(t.size, -40.0), np.full(t.size, 0.1), e)
>>> j.state_of('elevation', -40.0, 0.1), j.state_of('elevation', -40.0, -0.1)
('applied', 'testing')
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.feedforward.correction.settings import (
    DIRECTIONS,
    CorrectionError,
    CorrectionSettings,
    JudgeSettings,
)

if TYPE_CHECKING:   # (only the type: the judge works on any object with Correction's lookups)
    from gimbal_friction.feedforward.correction.core import Correction

__all__ = ['STATES', 'LoopJudge', 'correction_signature']

Array = NDArray[np.float64]
#: the states of a cell, by their code
STATES = ('untested', 'testing', 'applied', 'withdrawn')
UNTESTED, TESTING, APPLIED, WITHDRAWN = range(4)
#: a candidate whose largest value is below this is the model [N·m]
ZERO_NM = 1e-9
#: positions a cell's candidate is sampled at over the range its angle terms were fitted on [-]
SIGNATURE_POSITIONS = 8
#: the evidence gathered on a candidate counts this much once it changed size but not shape [-]
RESIZE_WEIGHT = 0.75
#: a group's contrast is clipped to ± this (a slew or a disturbance in one block of a group; e³ = 20 in mean square)
D_CLIP = 3.0
#: ln of this is added to a block's mean squared error (an error of exactly zero) [rad²/s²]
TINY_E2 = 1e-30


def correction_signature(correction: Correction, joint: str) -> Array:
    """The applied correction of ``joint`` along the motion [N·m] per cell, sampled at every speed octave's centre
    and at :data:`SIGNATURE_POSITIONS` positions over the range its angle terms were fitted on (the position is not
    used when there is no such range). Shape (2 directions, temperature bins, octaves × positions). This is what
    the judge compares to see whether a cell's candidate changed. The model friction it is evaluated with is the
    mean |model| of the bin's rows (1 N·mm where the bin has none)."""
    s = correction.settings
    nt, ns = s.n_temperature, s.speed_bins
    lut = correction.lookups[joint]
    if lut is None:
        return np.zeros((2, nt, ns))
    stats = correction.stats(joint)
    keys, sums = stats.rows()
    model = np.full(nt, 1e-3)
    if keys.size:
        _, b, *_ = stats.decode(keys)
        tot = np.bincount(b, weights=sums[:, 2], minlength=nt)
        cnt = np.bincount(b, weights=sums[:, 0], minlength=nt)
        model = np.where(cnt > 0, tot / np.maximum(cnt, 1e-300), model)
    speeds = s.min_speed_rad_s * 2.0 ** (np.arange(ns) + 0.5)
    rng = correction.joint(joint).angle_range
    positions = (np.linspace(rng[0], rng[1], SIGNATURE_POSITIONS) if rng is not None and rng[1] > rng[0]
                 else np.array([math.nan]))
    centres = np.array([s.centre_c(b) for b in range(nt)])
    out = np.zeros((2, nt, ns * positions.size))
    for d, sign in enumerate((1.0, -1.0)):
        t, v, p = np.meshgrid(centres, sign * speeds, positions, indexing='ij')
        m = np.broadcast_to(model[:, None, None], t.shape)
        along = correction.along_nm_array(joint, t, v, p, m)
        out[d] = along.reshape(nt, -1)
    return out


class _Block:
    """One block's schedule and its sums of squared loop error."""

    __slots__ = ('acc', 'epochs', 'flags', 'index', 'modes')

    def __init__(self, index: int, flags: NDArray[np.bool_], modes: NDArray[np.int8], epochs: NDArray[np.int64],
                 n_octaves: int) -> None:
        self.index = index
        self.flags, self.modes, self.epochs = flags, modes, epochs
        #: Σe² and samples per cell and speed octave (joints, 2, bins, octaves, 2)
        self.acc = np.zeros((*flags.shape, n_octaves, 2))


class LoopJudge:
    """The loop's judge of a correction of ``joints`` laid out by ``correction_settings`` (see the module notes).
    ConfigError: invalid settings, no joint."""

    def __init__(self, correction_settings: CorrectionSettings, joints: Sequence[str],
                 settings: JudgeSettings | None = None) -> None:
        s = settings if settings is not None else JudgeSettings()
        s.validate()
        correction_settings.validate()
        if not joints:
            raise CorrectionError('a loop judge needs at least one joint')
        self.settings, self.layout = s, correction_settings
        self.joints = tuple(joints)
        self._index = {j: i for i, j in enumerate(self.joints)}
        self._nt = correction_settings.n_temperature
        #: octave 0: slower than the correction's min_speed_rad_s; then its speed octaves
        self._no = correction_settings.speed_bins + 1
        self._g_test = max(2, round(1.0 / s.on_share))
        self._g_applied = max(2, round(1.0 / s.applied_off_share))
        self._shape = (len(self.joints), 2, self._nt)
        self.frozen = False
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the start: every cell untested, nothing measured."""
        shape = self._shape
        self.state = np.zeros(shape, dtype=np.int8)
        self.epoch = np.zeros(shape, dtype=np.int64)
        self.reason = np.full(shape, '', dtype=object)
        #: per cell: Σw, Σw d, Σw d² of the group contrasts (forgetting)
        self._sums = np.zeros((*shape, 3))
        self.groups = np.zeros(shape, dtype=np.int64)          #: groups counted since the test began [-]
        self.blocks_on = np.zeros(shape, dtype=np.int64)       #: blocks counted with the candidate on [-]
        self.blocks_off = np.zeros(shape, dtype=np.int64)      #: ... and off [-]
        self.contrast = np.full(shape, math.nan)               #: mean of d [-] (ln of a ratio of mean squares)
        self.std_error = np.full(shape, math.nan)              #: its standard error [-]
        self.z = np.full(shape, math.nan)                      #: contrast / std_error [-]
        self._ref: list[Array | None] = [None] * len(self.joints)
        self._open: dict[int, _Block] = {}
        #: closed blocks: index -> (flags, modes, epochs, x = ln mean e² (NaN: too few samples), samples)
        self._closed: dict[int, tuple[NDArray[np.bool_], NDArray[np.int8], NDArray[np.int64], Array, Array]] = {}
        self._block: int | None = None
        self._flags = np.zeros(shape, dtype=bool)
        self._positions: dict[tuple[int, int], NDArray[np.int64]] = {}
        self.late_samples = 0      #: loop-error samples whose block was already closed (or never entered) [-]
        self.samples = 0           #: loop-error samples counted [-]
        self.restarts = 0          #: tests (re)started on a new candidate [-]
        #: per joint, the temperature [°C] and velocity [rad/s] of the latest :meth:`use_candidate`
        self.last_motion: dict[str, tuple[float, float]] = {}

    def _cell(self, joint: str, temperature_c: float, velocity_rad_s: float) -> tuple[int, int, int] | None:
        j = self._index.get(joint)
        if j is None or temperature_c != temperature_c:
            return None
        s = self.layout
        b = int((temperature_c - s.temperature_min_c) // s.temperature_bin_c)
        b = 0 if b < 0 else self._nt - 1 if b >= self._nt else b
        return j, 0 if velocity_rad_s > 0.0 else 1, b

    def state_of(self, joint: str, temperature_c: float, velocity_rad_s: float) -> str:
        """The state of the cell of ``joint`` at ``temperature_c`` [°C], moving at ``velocity_rad_s`` [rad/s]."""
        cell = self._cell(joint, temperature_c, velocity_rad_s)
        if cell is None:
            raise CorrectionError(f'no cell of joint {joint!r} at {temperature_c} degC')
        return STATES[int(self.state[cell])]

    # ------------------------------------------------------------------ candidates
    def offer(self, joint: str, signature: ArrayLike) -> None:
        """The candidate of ``joint`` now: its :func:`correction_signature` (2, temperature bins, K) [N·m]. A cell
        whose candidate is the model becomes untested. A cell that is untested, or whose candidate moved by more
        than ``restart_relative`` of its size since its test began, starts a test (again)."""
        j = self._index.get(joint)
        if j is None:
            raise CorrectionError(f'joint {joint!r} is not judged ({", ".join(self.joints)})')
        sig = np.asarray(signature, dtype=float).reshape(2, self._nt, -1)
        size = np.abs(sig).max(axis=2)
        zero = ~(size > ZERO_NM)
        ref = self._ref[j]
        if ref is None or ref.shape != sig.shape:
            ref = np.zeros(sig.shape)
        rel = self.settings.restart_relative
        moved = np.sqrt(((sig - ref) ** 2).mean(axis=2))
        size_new, size_ref = np.sqrt((sig ** 2).mean(axis=2)), np.sqrt((ref ** 2).mean(axis=2))
        # the part of the new candidate that is no multiple of the old one (its shape changed)
        with np.errstate(invalid='ignore', divide='ignore'):
            k = np.where(size_ref > 0.0, (sig * ref).sum(axis=2) / np.maximum((ref * ref).sum(axis=2), 1e-300), 0.0)
        shape = np.sqrt(((sig - k[..., None] * ref) ** 2).mean(axis=2))
        st = self.state[j]
        changed = ~zero & (st != UNTESTED) & (moved > rel * np.maximum(size_new, size_ref))
        restart = ~zero & ((st == UNTESTED) | (changed & ((k <= 0.0) | (shape > rel * size_new))))
        scaled = changed & ~restart          # the same shape, another size (a rate-limited move, a refit)
        drop = zero & (st != UNTESTED)
        for mask, new in ((restart, TESTING), (drop, UNTESTED)):
            if not mask.any():
                continue
            st[mask] = new
            self.epoch[j][mask] += 1
            self._sums[j][mask] = 0.0
            for a in (self.groups, self.blocks_on, self.blocks_off):
                a[j][mask] = 0
            for a in (self.contrast, self.std_error, self.z):
                a[j][mask] = math.nan
            self.reason[j][mask] = 'test started on a new candidate' if new == TESTING else ''
        if scaled.any():    # the evidence on the old size counts less; a withdrawn cell is tested again
            again = scaled & (st == WITHDRAWN)
            st[again] = TESTING
            self._sums[j][scaled] *= RESIZE_WEIGHT
            for a in (self.groups, self.blocks_on, self.blocks_off):
                a[j][scaled] = np.floor(a[j][scaled] * RESIZE_WEIGHT)
            self.reason[j][again] = 'tested again: the candidate changed size'
        self.restarts += int(np.count_nonzero(restart | scaled))
        ref = ref.copy()
        new_ref = restart | drop | scaled
        ref[new_ref] = sig[new_ref]
        self._ref[j] = ref
        if new_ref.any() and self._block is not None:
            self._flags = self._schedule(self._block)    # (a cell untested now is off at once)

    def update_candidates(self, correction: Correction) -> None:
        """:meth:`offer` every judged joint's candidate as ``correction`` applies it (:func:`correction_signature`)."""
        for joint in self.joints:
            self.offer(joint, correction_signature(correction, joint))

    # ------------------------------------------------------------------ the schedule (the feedforward's path)
    def _positions_of(self, group_len: int, group: int) -> NDArray[np.int64]:
        key = (group_len, group)
        pos = self._positions.get(key)
        if pos is None:
            if len(self._positions) > 8:
                self._positions.clear()
            rng = np.random.default_rng([self.settings.seed, group_len, group & 0x7FFFFFFF])
            j, _, nt = self._shape      # (one draw for both directions of a bin: they are switched together)
            pos = np.broadcast_to(rng.integers(0, group_len, size=(j, 1, nt)), self._shape).copy()
            self._positions[key] = pos
        return pos

    def _schedule(self, block: int) -> NDArray[np.bool_]:
        """Whether each cell's candidate is on in ``block``. Both directions of a bin are on together or off
        together: the correction's part independent of the direction (an unbalance) switched on in one direction
        only would step at every reversal and kick the rate loop's integrator. So a bin is on only where each of
        its directions with a candidate is on (a withdrawn direction keeps the whole bin on the model)."""
        if self.frozen:
            flags = np.asarray(self.state == APPLIED)
        else:
            gt, ga = self._g_test, self._g_applied
            on_test = self._positions_of(gt, block // gt) == block % gt
            on_applied = self._positions_of(ga, block // ga) != block % ga
            flags = np.asarray(np.where(self.state == TESTING, on_test, (self.state == APPLIED) & on_applied))
        has = self.state != UNTESTED
        tied = (flags | ~has).all(axis=1, keepdims=True) & has.any(axis=1, keepdims=True)
        return np.asarray(np.broadcast_to(tied, self._shape).copy())

    def _enter(self, block: int) -> None:
        """Time reached ``block``: its schedule is drawn, and the blocks two or more before it are closed."""
        if self._block is not None and block <= self._block:
            return
        self._block = block
        self._flags = self._schedule(block)
        if not self.frozen:
            self._open[block] = _Block(block, self._flags.copy(), self.state.copy(), self.epoch.copy(), self._no)
        for k in sorted(i for i in self._open if i <= block - 2):
            self._close(self._open.pop(k))

    def _block_of(self, now_s: float) -> int:
        return math.floor(now_s / self.settings.block_s)

    def use_candidate(self, joint: str, temperature_c: float, velocity_rad_s: float, now_s: float) -> bool:
        """Whether the feedforward of ``joint`` at ``temperature_c`` [°C] and ``velocity_rad_s`` [rad/s] at time
        ``now_s`` [s] uses the correction (else the plain model). Cheap: one lookup, plus a new schedule once per
        block. An unknown joint, or a NaN temperature, gets False."""
        if self._block is None or now_s >= (self._block + 1) * self.settings.block_s:
            self._enter(self._block_of(now_s))
        self.last_motion[joint] = (temperature_c, velocity_rad_s)
        cell = self._cell(joint, temperature_c, velocity_rad_s)
        return cell is not None and bool(self._flags[cell])

    def use_candidate_array(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike,
                            now_s: float) -> NDArray[np.bool_]:
        """:meth:`use_candidate` for arrays of temperatures [°C] and velocities [rad/s] at one time [s]."""
        if self._block is None or now_s >= (self._block + 1) * self.settings.block_s:
            self._enter(self._block_of(now_s))
        t, v = np.broadcast_arrays(np.asarray(temperature_c, dtype=float), np.asarray(velocity_rad_s, dtype=float))
        j = self._index.get(joint)
        if j is None:
            return np.zeros(t.shape, dtype=bool)
        b = self._bins(t)
        d = np.where(v > 0.0, 0, 1)
        return np.asarray(np.where(np.isfinite(t), self._flags[j, d, b], False))

    def _bins(self, t: Array) -> NDArray[np.int64]:
        s = self.layout
        with np.errstate(invalid='ignore'):
            raw = np.floor((np.nan_to_num(t, nan=s.temperature_min_c) - s.temperature_min_c) / s.temperature_bin_c)
        return np.clip(raw, 0, self._nt - 1).astype(np.int64)

    def freeze(self, frozen: bool = True) -> None:
        """Stop judging (with False: resume): the applied cells use their candidate always, the others never;
        loop-error samples are ignored while frozen. Open blocks are closed first."""
        if frozen:
            for k in sorted(self._open):
                self._close(self._open.pop(k))
        self.frozen = frozen
        if self._block is not None:
            self._flags = self._schedule(self._block)

    # ------------------------------------------------------------------ the loop's error
    def observe(self, joint: str, stamp_s: ArrayLike, temperature_c: ArrayLike, velocity_rad_s: ArrayLike,
                rate_error_rad_s: ArrayLike) -> int:
        """Loop-error samples of ``joint`` at times ``stamp_s`` [s] (the clock of :meth:`use_candidate`): the LOS
        rate error [rad/s], with the temperature [°C] and the joint velocity [rad/s] the feedforward saw then (its
        cell and speed octave). Returns the samples counted. Samples in the first ``settle_s`` of a block, non-finite
        ones, and samples whose block is already closed are not counted (the last are counted in
        :attr:`late_samples`)."""
        if self.frozen:
            return 0
        jj = self._index.get(joint)
        if jj is None:
            raise CorrectionError(f'joint {joint!r} is not judged ({", ".join(self.joints)})')
        ts, t, v, e = (a.ravel() for a in np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (
            stamp_s, temperature_c, velocity_rad_s, rate_error_rad_s))))
        ok = np.isfinite(ts) & np.isfinite(t) & np.isfinite(v) & np.isfinite(e)
        if not ok.any():
            return 0
        ts, t, v, e = ts[ok], t[ok], v[ok], e[ok]
        bs = self.settings.block_s
        blk = np.floor(ts / bs).astype(np.int64)
        newest = int(blk.max())
        if self._block is None or newest > self._block:
            self._enter(newest)
        keep = ts - blk * bs >= self.settings.settle_s
        blk, t, v, e = blk[keep], t[keep], v[keep], np.minimum(np.abs(e[keep]), self.settings.error_cap_rad_s)
        b = self._bins(t)
        d = np.where(v > 0.0, 0, 1)
        s = self.layout
        a = np.abs(v)
        with np.errstate(divide='ignore'):
            o = np.where(a >= s.min_speed_rad_s, np.floor(np.log2(np.maximum(a, 1e-300) / s.min_speed_rad_s)) + 1, 0)
        o = np.clip(o, 0, self._no - 1).astype(np.int64)
        flat = (d * self._nt + b) * self._no + o
        size = 2 * self._nt * self._no
        counted = 0
        for k in np.unique(blk).tolist():
            rec = self._open.get(int(k))
            sel = blk == k
            if rec is None:
                self.late_samples += int(np.count_nonzero(sel))
                continue
            acc = rec.acc[jj].reshape(size, 2)
            acc[:, 0] += np.bincount(flat[sel], weights=e[sel] * e[sel], minlength=size)
            acc[:, 1] += np.bincount(flat[sel], minlength=size)
            counted += int(np.count_nonzero(sel))
        self.samples += counted
        return counted

    def observe_latest(self, joint: str, stamp_s: float, rate_error_rad_s: float) -> int:
        """:meth:`observe` of one loop-error sample of ``joint`` at ``stamp_s`` [s], in the cell and speed octave of
        the feedforward's latest :meth:`use_candidate` of that joint (the node: the loop error arrives on its own
        topic); 0 before any."""
        last = self.last_motion.get(joint)
        if last is None:
            return 0
        return self.observe(joint, stamp_s, last[0], last[1], rate_error_rad_s)

    # ------------------------------------------------------------------ verdicts
    def _close(self, rec: _Block) -> None:
        """A block is over: its x per cell and octave kept, the groups it completes judged."""
        n = rec.acc[..., 1]
        with np.errstate(divide='ignore', invalid='ignore'):
            x = np.where(n >= self.settings.min_block_samples, np.log(rec.acc[..., 0] / np.maximum(n, 1.0) + TINY_E2),
                         math.nan)
        self._closed[rec.index] = (rec.flags, rec.modes, rec.epochs, x, n)
        gmax = max(self._g_test, self._g_applied)
        for k in [i for i in self._closed if i <= rec.index - gmax]:
            del self._closed[k]
        for g, mode in ((self._g_test, TESTING), (self._g_applied, APPLIED)):
            if rec.index % g == g - 1:
                self._judge_group(range(rec.index - g + 1, rec.index + 1), mode)

    def _judge_group(self, blocks: range, mode: int) -> None:
        recs = [self._closed.get(i) for i in blocks]
        if any(r is None for r in recs):
            return
        flags = np.stack([r[0] for r in recs if r is not None])
        modes = np.stack([r[1] for r in recs if r is not None])
        epochs = np.stack([r[2] for r in recs if r is not None])
        x = np.stack([r[3] for r in recs if r is not None])
        n = np.stack([r[4] for r in recs if r is not None])
        cells = (modes == mode).all(axis=0) & (epochs == self.epoch[None]).all(axis=0) & (self.state == mode)
        cells &= flags.any(axis=0) & (~flags).any(axis=0)
        if not cells.any():
            return
        f = flags[..., None]
        have = np.isfinite(x)
        with np.errstate(invalid='ignore', divide='ignore'):
            k_on = (have & f).sum(axis=0)
            k_off = (have & ~f).sum(axis=0)
            x_on = np.where(have & f, x, 0.0).sum(axis=0) / k_on
            x_off = np.where(have & ~f, x, 0.0).sum(axis=0) / k_off
            n_on = np.where(have & f, n, 0.0).sum(axis=0)
            n_off = np.where(have & ~f, n, 0.0).sum(axis=0)
            both = (k_on > 0) & (k_off > 0)
            w = np.where(both, np.minimum(n_on, n_off), 0.0)
            wsum = w.sum(axis=-1)
            dg = np.where(both, x_on - x_off, 0.0)
            d = np.clip((w * dg).sum(axis=-1) / wsum, -D_CLIP, D_CLIP)
        cells &= wsum > 0.0
        if not cells.any():
            return
        blocks_on = (flags & (have.any(axis=-1))).sum(axis=0)
        blocks_off = (~flags & (have.any(axis=-1))).sum(axis=0)
        lam = 1.0 - 1.0 / self.settings.memory_groups
        sums = self._sums
        sums[cells] *= lam
        sums[cells, 0] += 1.0
        sums[cells, 1] += d[cells]
        sums[cells, 2] += d[cells] ** 2
        self.groups[cells] += 1
        self.blocks_on[cells] += blocks_on[cells]
        self.blocks_off[cells] += blocks_off[cells]
        self._verdicts(cells)

    def _verdicts(self, cells: NDArray[np.bool_]) -> None:
        s = self.settings
        for idx in zip(*np.nonzero(cells), strict=True):
            c = tuple(int(i) for i in idx)
            wt, s1, s2 = (float(v) for v in self._sums[c])
            mean = s1 / wt
            var = (s2 - wt * mean * mean) / (wt - 1.0) if wt > 1.0 else math.nan
            se = math.sqrt(max(var, 0.0) / wt) if var == var else math.nan
            z = mean / se if se > 0.0 else (0.0 if mean == 0.0 or se != se else math.copysign(math.inf, mean))
            self.contrast[c], self.std_error[c], self.z[c] = mean, se, z
            enough = self.blocks_on[c] >= s.min_blocks and self.blocks_off[c] >= s.min_blocks and wt > 1.0
            if not enough:
                continue
            ratio = math.exp(mean)
            if self.state[c] == TESTING:
                if z < -s.z:
                    self.state[c] = APPLIED
                    self.reason[c] = (f'loop error lower with it: mean square x{ratio:.3f}, {-z:.1f} standard errors '
                                      f'(needs {s.z:g})')
                elif z > s.stop_z:
                    self.state[c] = WITHDRAWN
                    self.reason[c] = (f'test stopped: loop error higher with it: mean square x{ratio:.3f}, '
                                      f'{z:.1f} standard errors')
                elif self.blocks_on[c] >= s.max_blocks:
                    self.state[c] = WITHDRAWN
                    self.reason[c] = (f'no gain shown in {int(self.blocks_on[c])} blocks on (z {z:.1f}, needs '
                                      f'{-s.z:g})')
            elif self.state[c] == APPLIED and z > s.stop_z:
                self.state[c] = WITHDRAWN
                self.reason[c] = (f'falsified: loop error higher with it: mean square x{ratio:.3f}, {z:.1f} '
                                  f'standard errors')
            if self.state[c] == WITHDRAWN:   # the bin's directions are switched together: both to the model
                other = (c[0], 1 - c[1], c[2])
                if self.state[other] in (TESTING, APPLIED):
                    self.state[other] = WITHDRAWN
                    self.reason[other] = (f'withdrawn with the {DIRECTIONS[c[1]]} direction of its bin (switched '
                                          'together)')

    # ------------------------------------------------------------------ reports
    def applied_mask(self, joint: str) -> NDArray[np.bool_]:
        """Cells (2, temperature bins) of ``joint`` the judge applied."""
        return np.asarray(self.state[self._index[joint]] == APPLIED)

    def cells(self, joint: str) -> list[dict[str, Any]]:
        """One record per cell of ``joint`` that is not untested or has blocks counted: ``direction``, ``bin``,
        ``centre_c``, ``state``, ``reason``, ``groups``, ``blocks_on``, ``blocks_off``, ``contrast`` (mean of
        ln(mean e² on / off) [-]), ``ratio`` (exp of it: the loop's mean square with the candidate over without),
        ``std_error``, ``z``."""
        j = self._index[joint]
        out = []
        for d in range(2):
            for b in range(self._nt):
                st = int(self.state[j, d, b])
                if st == UNTESTED and self.groups[j, d, b] == 0:
                    continue
                if st == TESTING and self.groups[j, d, b] == 0:
                    continue    # (a candidate held over a bin the gimbal never visited)
                m = float(self.contrast[j, d, b])
                out.append({'direction': DIRECTIONS[d], 'bin': b, 'centre_c': self.layout.centre_c(b),
                            'state': STATES[st], 'reason': str(self.reason[j, d, b]),
                            'groups': int(self.groups[j, d, b]), 'blocks_on': int(self.blocks_on[j, d, b]),
                            'blocks_off': int(self.blocks_off[j, d, b]), 'contrast': m,
                            'ratio': math.exp(m) if m == m else math.nan,
                            'std_error': float(self.std_error[j, d, b]), 'z': float(self.z[j, d, b])})
        return out

    def summary(self) -> dict[str, Any]:
        """Cells per state (``cells_testing`` counts cells with blocks counted), the loop-error samples counted
        and late, the tests started, whether frozen, and per joint the :meth:`cells`."""
        joints = {j: self.cells(j) for j in self.joints}
        out: dict[str, Any] = {'judged_by_loop': True, 'frozen': self.frozen, 'samples': self.samples,
                               'late_samples': self.late_samples, 'restarts': self.restarts,
                               'block_s': self.settings.block_s, 'on_share': 1.0 / self._g_test}
        for name in STATES[1:]:
            out[f'cells_{name}'] = sum(1 for cs in joints.values() for c in cs if c['state'] == name)
        return {**out, 'joints': joints}
