"""In-service learning of a correction: gated, scored before it is learned, applied at a limited rate (pure numpy).

One job in one module: :class:`Learner` (its gate, its pending samples and its rate-limited step share one state).

Samples arrive one at a time (the node's ``/gimbal/friction/measured_detail``, :meth:`Learner.update`) or in
batches (the loop study, :meth:`Learner.update_many`); the gate
(:func:`~gimbal_friction.feedforward.correction.stats.gate_code`) refuses the unusable and the implausible at once.
Accepted samples wait until the next step (every ``step_period_s``): there they are scored by the candidate they
have not been learned into (the guard, :meth:`~gimbal_friction.feedforward.correction.core.Correction.score`), then
kept; the candidate is refitted (ripple periods searched again as the data grows), the guard's verdicts give the
target, and the applied terms move towards it by at most ``max_rate_nm_per_min`` per minute (a speed node and a trend
coefficient by that torque; a ripple coefficient by that torque over the bin's mean |model|; the step's time is
capped at ``step_period_s``, so a pause does not allow a jump). A temperature bin moves once both directions have
samples: a torque independent of the direction learned one direction at a time would be compensated in one
direction only and kick the rate loop's integrator at every reversal.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.xp import SCALAR
from gimbal_friction.feedforward.correction.core import Correction, applied_bound_nm
from gimbal_friction.feedforward.correction.fit import Params
from gimbal_friction.feedforward.correction.settings import LearningSettings
from gimbal_friction.feedforward.correction.stats import REASONS, gate_code

__all__ = ['R_FROZEN', 'R_UNKNOWN', 'Learner', 'learn_rows', 'learn_step', 'move_towards']

Array = NDArray[np.float64]
R_FROZEN, R_UNKNOWN = 'frozen', 'unknown joint'
#: two ripple periods closer than this relative difference of frequency are the same slot of the applied ripple [-]
SAME_PERIOD = 0.01
#: most ripple slots an applied correction carries (periods fading out included) [-]
MAX_SLOTS = 16


def move_towards(applied: Params, target: Params, limit_nm: float, model_nm: Array, paired: NDArray[np.bool_]
                 ) -> Params:
    """``applied`` moved towards ``target`` by at most ``limit_nm`` [N·m] (a ripple coefficient by ``limit_nm`` over
    the bin's ``model_nm`` [N·m]), in the temperature bins ``paired`` only. Ripple periods of the target that the
    applied terms do not hold get a new slot starting at 0; slots the target no longer holds move to 0 and go."""
    slots = applied.periods_rad.tolist()
    coefs = [applied.ripple[:, k, :] for k in range(len(slots))]
    want = [np.zeros(coefs[0].shape) if coefs else None for _ in slots]
    nt = applied.speed_nm.shape[1]
    for k, period in enumerate(target.periods_rad.tolist()):
        match = next((i for i, p in enumerate(slots) if abs(p / period - 1.0) < SAME_PERIOD), None)
        if match is None:
            if len(slots) >= MAX_SLOTS:
                continue
            slots.append(period)
            coefs.append(np.zeros((nt, 2)))
            want.append(target.ripple[:, k, :])
        else:
            slots[match] = period
            want[match] = target.ripple[:, k, :]
    speed = applied.speed_nm.copy()
    trend = applied.trend_nm.copy()
    lim = paired.astype(float) * limit_nm
    speed += np.clip(target.speed_nm - speed, -lim[None, :, None], lim[None, :, None])
    trend += np.clip(target.trend_nm - trend, -lim[:, None], lim[:, None])
    rel = (lim / np.maximum(model_nm, 1e-9))[:, None]
    out_p, out_c = [], []
    for period, c, w in zip(slots, coefs, want, strict=True):
        goal = np.zeros(c.shape) if w is None else w
        new = c + np.clip(goal - c, -rel, rel)
        if w is None and not np.any(np.abs(new) > 1e-15):
            continue                                    # faded out
        out_p.append(period)
        out_c.append(new)
    ripple = np.stack(out_c, axis=1) if out_c else np.zeros((nt, 0, 2))
    return Params(speed, np.asarray(out_p, dtype=float), ripple, trend)


def learn_rows(c: Correction, rows: dict[str, Array]) -> None:
    """Score ``rows`` (per joint, as :meth:`Learner.take_pending` gives them) by ``c``'s candidate, then keep them
    in its rows (test, then train; the gate already passed)."""
    for joint, a in rows.items():
        t, v, p, r, m = a.T
        c.score(joint, t, v, p, r, m)
        c._keep(c.joint(joint), t, v, p, r, m)


def learn_step(c: Correction, rows: dict[str, Array], limit_nm: float) -> bool:
    """The expensive part of :meth:`Learner.step`, on ``c`` in place: learn ``rows`` (:func:`learn_rows`), refit
    every joint with samples (ripple periods searched again as the data grows) and move its applied terms towards
    the target by at most ``limit_nm`` [N·m]; True if an applied term changed."""
    learn_rows(c, rows)
    changed = False
    for j in c.identity.joints:
        if c.stats(j).samples() == 0:
            continue
        fit = c.refit(j)
        has = c.has_data(j)
        paired = has[0] & has[1]
        model = np.maximum(fit.model_nm.max(axis=0), c.settings.floor_nm)
        old = c.applied(j)
        new = move_towards(old, c.target(j), limit_nm, model, paired)
        bound = applied_bound_nm(c.stats(j))        # (rows' means move as samples arrive)
        np.clip(new.speed_nm, -bound[None, :, None], bound[None, :, None], out=new.speed_nm)
        np.clip(new.trend_nm, -10.0 * bound[:, None], 10.0 * bound[:, None], out=new.trend_nm)
        if not (np.array_equal(new.speed_nm, old.speed_nm) and np.array_equal(new.trend_nm, old.trend_nm)
                and np.array_equal(new.periods_rad, old.periods_rad) and np.array_equal(new.ripple, old.ripple)):
            c.joint(j).applied = new
            c.rebuild(j)
            changed = True
    return changed


class Learner:
    """Learns a :class:`~gimbal_friction.feedforward.correction.core.Correction` online (see the module notes).

    ``correction`` (learned so far, or empty) is updated in place; lookups use ``learner.correction``.
    """

    def __init__(self, correction: Correction, settings: LearningSettings) -> None:
        settings.validate()
        self.correction, self.settings = correction, settings
        self.frozen = False
        self.accepted = 0                      #: samples accepted (learned, pending or discarded) [-]
        self.rejected: dict[str, int] = {}     #: samples refused, per reason [-]
        #: samples accepted but cleared before a step learned them (a reset, a new correction) [-]
        self.discarded = 0
        self._last_step_s: float | None = None
        self._pending: dict[str, list[list[float]]] = {j: [] for j in correction.identity.joints}

    # ------------------------------------------------------------------ samples
    def update(self, joint: str, temperature_c: float, velocity_rad_s: float, position_rad: float, residual_nm: float,
               model_nm: float, now_s: float, temperature_fresh: bool = True) -> str | None:
        """One estimator sample at time ``now_s`` [s]: residual = measured − model friction along the motion
        [N·m], model friction [N·m], temperature [°C], velocity [rad/s], position [rad]; the reason if refused
        (frozen, unknown joint, or the gate). Accepted samples are learned at the next step."""
        if self.frozen:
            reason: str | None = R_FROZEN
        elif joint not in self._pending:
            reason = R_UNKNOWN
        else:
            code = gate_code(self.correction.settings, temperature_c, velocity_rad_s, residual_nm, model_nm,
                             temperature_fresh, SCALAR)
            reason = REASONS[code] if code else None
        if reason is None:
            self.accepted += 1
            self._pending[joint].append([temperature_c, velocity_rad_s, position_rad, residual_nm, model_nm])
        else:
            self.rejected[reason] = self.rejected.get(reason, 0) + 1
        if self._last_step_s is None or not 0.0 <= now_s - self._last_step_s < self.settings.step_period_s:
            self.step(now_s)
        return reason

    def update_many(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike, position_rad: ArrayLike,
                    residual_nm: ArrayLike, model_nm: ArrayLike, temperature_fresh: ArrayLike = True
                    ) -> dict[str, int]:
        """:meth:`update` for arrays of samples (no step; units as :meth:`update`); the refused per reason."""
        c = self.correction
        arrays = c._arrays(temperature_c, velocity_rad_s, position_rad, residual_nm, model_nm,
                           temperature_fresh)
        n = arrays[0].size
        if self.frozen or joint not in self._pending:
            reason = R_FROZEN if self.frozen else R_UNKNOWN
            self.rejected[reason] = self.rejected.get(reason, 0) + n
            return {reason: n}
        t, v, p, r, m, fresh = arrays
        code = c.gate(t, v, r, m, fresh.astype(bool))
        ok = code == 0
        self.accepted += int(np.count_nonzero(ok))
        self._pending[joint].extend(np.stack([t[ok], v[ok], p[ok], r[ok], m[ok]], axis=1).tolist())
        out = {REASONS[k]: int(k_n) for k, k_n in enumerate(np.bincount(code, minlength=len(REASONS))) if k and k_n}
        for reason, k_n in out.items():
            self.rejected[reason] = self.rejected.get(reason, 0) + k_n
        return out

    @property
    def pending(self) -> int:
        """Accepted samples not yet learned (they are at the next step or :meth:`flush`) [-]."""
        return sum(len(p) for p in self._pending.values())

    def flush(self) -> None:
        """Score the pending samples by the candidate, then keep them (test, then train)."""
        learn_rows(self.correction, self.take_pending())

    def take_pending(self) -> dict[str, Array]:
        """The pending samples per joint (rows of temperature [°C], velocity [rad/s], position [rad], residual
        [N·m], model [N·m]), taken: they are no longer pending."""
        out = {}
        for joint, rows in self._pending.items():
            if rows:
                out[joint] = np.asarray(rows, dtype=float)
                rows.clear()
        return out

    # ------------------------------------------------------------------ step
    def take_step(self, now_s: float) -> tuple[dict[str, Array], float] | None:
        """The cheap part of :meth:`step` at ``now_s`` [s]: the pending samples (taken) and the step's rate limit
        [N·m], or None when nothing moves (frozen, the first step, time running backwards)."""
        last, self._last_step_s = self._last_step_s, now_s
        if self.frozen or last is None or not now_s > last:
            return None
        limit = self.settings.max_rate_nm_per_min * min(now_s - last, self.settings.step_period_s) / 60.0
        return self.take_pending(), limit

    def step(self, now_s: float) -> bool:
        """Learn the pending samples, refit the candidate and move the applied terms towards the target for the time
        since the last step (at most ``step_period_s``) [s]; True if an applied term changed. Nothing moves while
        frozen or when time runs backwards."""
        job = self.take_step(now_s)
        return job is not None and learn_step(self.correction, *job)

    def freeze(self, frozen: bool = True) -> None:
        """Stop (or, with False, resume) learning; the applied correction stays as it is (pending samples are
        learned first)."""
        if frozen:
            self.flush()
        self.frozen = frozen

    def discard_pending(self) -> None:
        """Clear the pending samples unlearned, counted in :attr:`discarded` (so accepted = learned + pending +
        discarded holds)."""
        self.discarded += self.pending
        for rows in self._pending.values():
            rows.clear()

    def reset(self) -> None:
        """Back to the pure model at once: an empty correction (the counters stay: the pending samples are
        :attr:`discarded`)."""
        self.discard_pending()
        self.correction.reset()

    def snapshot(self) -> Correction:
        """An independent copy of the correction with every accepted sample learned, to save or publish."""
        self.flush()
        return copy.deepcopy(self.correction)

    @property
    def state(self) -> str:
        """``frozen``, ``saturated`` (a cell's learned value is clipped by the bound) or ``active``."""
        if self.frozen:
            return 'frozen'
        return 'saturated' if self.correction_summary()['saturated_cells'] else 'active'

    def cells(self, joint: str) -> list[dict[str, Any]]:
        """The correction's cells with each cell's ``state``: ``frozen``, ``saturated``, ``held back`` or
        ``active``."""
        out = []
        for rec in self.correction_cells(joint):
            state = ('frozen' if self.frozen else 'saturated' if rec['saturated'] else
                     'active' if rec['applied'] else 'held back')
            out.append({**rec, 'state': state})
        return out

    def summary(self) -> dict[str, Any]:
        """The correction's summary with the state and the accepted/refused sample counts (status, diagnostics)."""
        return {'state': self.state, 'accepted': self.accepted, 'rejected': dict(self.rejected),
                'pending': self.pending, **self.correction_summary()}

    def correction_summary(self) -> dict[str, Any]:
        """The correction's :meth:`~gimbal_friction.feedforward.correction.core.Correction.summary` (a learner whose
        refits run elsewhere gives the one its worker made with the last fit)."""
        return self.correction.summary()

    def correction_cells(self, joint: str) -> list[dict[str, Any]]:
        """The correction's :meth:`~gimbal_friction.feedforward.correction.core.Correction.cells` of ``joint`` (as
        :meth:`correction_summary`)."""
        return self.correction.cells(joint)

    def replace(self, correction: Correction) -> None:
        """Learn on from ``correction`` (the counters kept; the pending samples cleared, counted as discarded)."""
        self.discard_pending()
        self.correction = correction
        self._pending = {j: [] for j in correction.identity.joints}

    def start(self) -> None:
        """Start the worker refits run in (here: none)."""

    def poll(self) -> bool:
        """Take a finished refit in (here: none, :meth:`step` refits at once); True if an applied term changed."""
        return False

    def drain(self) -> None:
        """Learn every accepted sample (waiting for a refit in progress elsewhere)."""
        self.flush()

    def close(self) -> None:
        """Release what the learner holds (here: nothing)."""


_ = math
