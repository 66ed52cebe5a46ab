"""The loop study over generated truths (``gimbal-friction loop-study --truths N``): goal fractions on gimbals nobody
described to the suite.

One job in one module: :func:`truths_study` (each truth of :func:`~gimbal_friction.sim.truths.draw_truth` run through
the whole study, in parallel processes, and the learning goals counted over all of them).

A learned correction is judged on truths it was not tuned to: truth ``k`` of the generator is the same on every
machine (seeded), so a fraction measured here can be measured again anywhere, and a truth that misses a goal can be
studied alone (``--out`` writes each truth as a ``--truth`` file and its base motion as a ``--config`` file).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from gimbal_friction.sim.study import LEARNING_GOALS, LearnSetup, goal_checks, goal_legend
from gimbal_friction.sim.truths import draw_truth, truth_mapping

__all__ = ['fractions', 'truths_study', 'truths_text', 'write_truth_files']

#: the record fields kept per truth (the rest of a study's record is in the single-truth study)
KEPT = ('case', 'profile', 'temperature_c', 'rate_error_rms_rad_s')


def _one(args: tuple[Any, int, dict[str, Any]]) -> dict[str, Any]:
    """One truth through the whole study (a worker process)."""
    from gimbal_friction.runs.loop_study import study
    inputs, seed, kw = args
    t0 = time.perf_counter()
    truth = draw_truth(seed, inputs.sim)
    result = study(inputs._replace(sim=truth.config(inputs.sim)), **kw)
    goals = [g for g in goal_checks(result.records) if g['goal'] in LEARNING_GOALS]
    summaries = {k: c.summary() for k, c in (result.learned or {}).items()}
    return {'seed': seed, 'truth': truth_mapping(truth), 'base_scale': truth.base_scale,
            'sim': {k: list(v) if isinstance(v, tuple) else v for k, v in truth.sim.items()},
            'describe': truth.describe(), 'goals': goals, 'records': [{k: r[k] for k in KEPT} for r in result.records],
            'learned': {k: {f: s[f] for f in ('samples', 'cells_applied', 'cells_held_back', 'max_abs_ripple',
                                              'max_abs_unbalance_nm')} | {
                'periods_deg': [q['period_deg'] for q in s['joints'][next(iter(s['joints']))]['periods']]}
                for k, s in summaries.items()},
            'wall_s': round(time.perf_counter() - t0, 1)}


def fractions(truths: Sequence[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per learning goal over every truth and cell: cells checked, met, the fraction met and the worst value."""
    out: dict[str, dict[str, Any]] = {}
    for goal, what in LEARNING_GOALS.items():
        mine = [g for t in truths for g in t['goals'] if g['goal'] == goal]
        if not mine:
            continue
        met = sum(bool(g['met']) for g in mine)
        worst = max(mine, key=lambda g: g['value'])
        out[goal] = {'what': what, 'cells': len(mine), 'met': met, 'fraction': met / len(mine),
                     'truths_all_met': sum(all(g['met'] for g in t['goals'] if g['goal'] == goal) for t in truths),
                     'worst': worst['value'],
                     'worst_at': {'seed': next(t['seed'] for t in truths if worst in t['goals']),
                                  'profile': worst['profile'], 'temperature_c': worst['temperature_c']}}
    return out


def truths_study(inputs: Any, n: int, first_seed: int = 0, *, jobs: int = 1, short: bool = False,
                 temperatures: Sequence[float] | None = None, profiles: Sequence[str] | None = None,
                 cases: Sequence[str] | None = None, learn: LearnSetup | None = None,
                 progress: Callable[[str, float], None] | None = None) -> dict[str, Any]:
    """The study (:func:`~gimbal_friction.runs.loop_study.study`) for truths ``first_seed`` … ``first_seed + n − 1``
    of the generator, ``jobs`` at a time in worker processes; ``inputs`` as
    :func:`~gimbal_friction.runs.loop_study.load_study_inputs` (the configuration under test and the simulator's
    other settings; each truth replaces the truth and scales the base motion). Returns ``truths`` (one record per
    truth: seed, its parameters, goals, records, what was learned) and ``fractions`` (:func:`fractions`)."""
    kw: dict[str, Any] = {'short': short, 'learn': learn}
    if temperatures is not None:
        kw['temperatures'] = list(temperatures)
    if profiles is not None:
        kw['profiles'] = list(profiles)
    if cases is not None:
        kw['cases'] = list(cases)
    seeds = list(range(first_seed, first_seed + n))
    done: list[dict[str, Any]] = []
    work = [(inputs, s, kw) for s in seeds]
    if jobs <= 1:
        for k, item in enumerate(work):
            done.append(_one(item))
            if progress is not None:
                progress(f'truth {k + 1} of {n} (seed {item[1]})', (k + 1) / n)
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for k, rec in enumerate(pool.map(_one, work)):
                done.append(rec)
                if progress is not None:
                    progress(f'truth {k + 1} of {n} (seed {rec["seed"]})', (k + 1) / n)
    return {'truths': done, 'fractions': fractions(done), 'first_seed': first_seed, 'n': n, 'short': short}


def truths_text(doc: dict[str, Any]) -> str:
    """The fractions and one line per truth, as text."""
    from gimbal_friction.common.text import format_table
    rows = [[g, f'{f["met"]} of {f["cells"]}', f'{100 * f["fraction"]:.1f} %', f'{f["truths_all_met"]}',
             f'{f["worst"]:.3f}', (f'seed {f["worst_at"]["seed"]} {f["worst_at"]["profile"]} '
                                   f'{f["worst_at"]["temperature_c"]:+g} degC')] for g, f in doc['fractions'].items()]
    out = [(f'loop study over {doc["n"]} generated truths (seeds {doc["first_seed"]}..'
            f'{doc["first_seed"] + doc["n"] - 1}, {"short" if doc["short"] else "full"} profiles): learning goals'),
           format_table(rows, ['goal', 'cells met', 'fraction', 'truths all met', 'worst', 'where']),
           'goals: what each checks', *goal_legend(list(doc['fractions'])), '']
    for t in doc['truths']:
        missed = [g for g in t['goals'] if not g['met']]
        out.append(f'{t["describe"]}: {len(t["goals"]) - len(missed)} of {len(t["goals"])} met'
                   + (f'; missed: {", ".join(sorted({g["goal"] for g in missed}))}' if missed else ''))
    return '\n'.join(out) + '\n'


def write_truth_files(folder: Path, doc: dict[str, Any]) -> list[Path]:
    """Each truth as ``truth_<seed>.yaml`` (a ``loop-study --truth`` file) and its base motion as
    ``sim_<seed>.yaml`` (a ``--config`` file), so one truth can be studied alone."""
    import yaml
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for t in doc['truths']:
        truth = folder / f'truth_{t["seed"]}.yaml'
        truth.write_text(yaml.safe_dump({'gimbal_sim': {'ros__parameters': t['truth']}}, sort_keys=False))
        sim = folder / f'sim_{t["seed"]}.yaml'
        sim.write_text(yaml.safe_dump({'gimbal_sim': {'ros__parameters': t['sim']}}, sort_keys=False))
        out += [truth, sim]
    return out

