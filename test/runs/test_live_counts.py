"""The main job's account of its live run (gimbal_friction/runs/live_counts.py), from statuses as the nodes publish
them on /diagnostics: what each node counted, whether the counts settled, and whether the run degraded."""

from __future__ import annotations

from gimbal_friction.runs.live_counts import Reports, degradations, describe, summarize, verdict

JS, TEMP, CUR = '/joint_states', '/gimbal/temperature', '/gimbal/motor_current'
FF, MEAS, DETAIL = '/gimbal/friction/feedforward', '/gimbal/friction/measured', '/gimbal/friction/measured_detail'


def _replay(state: str = 'finished') -> dict[str, str]:
    return {'state': state, f'published: {JS}': '100', f'publisher_gid: {JS}': '0a', f'published: {TEMP}': '10',
            f'publisher_gid: {TEMP}': '0b', f'published: {CUR}': '100', f'publisher_gid: {CUR}': '0c'}


def _feedforward(published: int, js: int, source: str = 'measured', lost_js: int = 0) -> dict[str, str]:
    return {'temperature_source': source, 'published': str(published), f'received: {JS}': str(js),
            f'lost: {JS}': str(lost_js), f'received: {TEMP}': '10', f'lost: {TEMP}': '0',
            f'received: {DETAIL}': '80', f'lost: {DETAIL}': '0'}


def _estimator() -> tuple[dict[str, str], dict[str, str]]:
    inputs = {f'received: {t}': str(n) for t, n in ((JS, 100), (TEMP, 10), (CUR, 100))}
    inputs.update({f'lost: {t}': '0' for t in (JS, TEMP, CUR)})
    return inputs, {'accepted': '80', 'rejected: dwell': '15', 'rejected: outside position window': '5'}


def _logger(no_feedforward: int = 0, waiting: int = 0, sent: bool = True, ff: int = 100) -> dict[str, str]:
    v = {'residuals_logged': '80', 'paired_with_feedforward': str(80 - no_feedforward),
         'no_feedforward': str(no_feedforward), 'waiting_for_feedforward': str(waiting), 'dropped': '0',
         'messages_logged': '530', 'received: /diagnostics': '7', 'lost: /diagnostics': '0'}
    for topic, n in ((JS, 100), (TEMP, 10), (CUR, 100), (FF, ff), (MEAS, 80), (DETAIL, 80)):
        v[f'received: {topic}'], v[f'lost: {topic}'] = str(n), '0'
        if sent and topic in (JS, TEMP, CUR):
            v[f'sent: {topic}'] = str(n)
    return v


def _run(reports: Reports, ff: list[dict[str, str]], logger: dict[str, str]) -> None:
    inputs, joint = _estimator()
    reports.add('gimbal_friction/chamber_replay', _replay())
    for values in ff:
        reports.add('gimbal_friction/feedforward/elevation', values)
        reports.add('gimbal_friction/feedforward/learning', {'state': 'off'})
        reports.add('gimbal_friction/estimator', inputs)
        reports.add('gimbal_friction/estimator/elevation', joint)
        reports.add('gimbal_friction/residual_logger', {**logger, 'received: /diagnostics': str(len(ff))})


def test_a_clean_run_settles_and_did_not_degrade():
    r = Reports()
    # before the replay: no temperature yet (fallback), nothing published: not a report about any output
    _run(r, [_feedforward(0, 0, 'fallback_temperature'), _feedforward(50, 50), _feedforward(100, 100),
             _feedforward(100, 100)], _logger())
    assert r.settled()  # the counts twice alike (the diagnostics the logger keeps receiving do not count)
    s = summarize(r)
    assert s['sent'] == {JS: 100, TEMP: 10, CUR: 100, FF: 100, MEAS: 80, DETAIL: 80}
    assert s['friction_feedforward']['reports'] == 2 and s['friction_feedforward']['used_instead'] == {}
    assert s['friction_estimator']['refused'] == {} and s['friction_estimator']['accepted'] == 80
    assert degradations(s) == []
    assert verdict(s).startswith('the live run did not degrade')
    lines = describe(s)
    assert lines[0] == 'chamber_replay        sent 100 joint states, 10 temperatures, 100 currents'
    assert '100 of 100 joint states (lost 0)' in lines[1] and 'no fresh temperature in 0 of 2 reports' in lines[1]
    assert 'accepted 80 samples; refused: none; not in steady state: dwell 15, outside position window 5' in lines[2]
    assert 'logged 80 rows: 80 with the feedforward, 0 without' in lines[3]


def test_a_degraded_run_says_what_the_nodes_counted():
    r = Reports()
    _run(r, [_feedforward(40, 40), _feedforward(70, 70, 'fallback_temperature', lost_js=20),
             _feedforward(80, 80, lost_js=20), _feedforward(80, 80, lost_js=20)], _logger(no_feedforward=12, ff=80))
    s = summarize(r)
    found = degradations(s)
    assert found == ['friction_feedforward lost 20 of 100 joint states, had no fresh temperature in 1 of 3 reports '
                     'while publishing (used: fallback_temperature 1)',
                     'residual_logger logged 12 measurements without a feedforward']
    assert verdict(s).startswith('the live run degraded: friction_feedforward lost 20 of 100 joint states')
    assert "'model' column (the feedforward as published live) may differ from replay" in verdict(s)


def test_a_topic_that_never_arrived_is_missing_whole():
    r = Reports()
    logger = _logger()
    del logger[f'received: {MEAS}'], logger[f'lost: {MEAS}']
    _run(r, [_feedforward(100, 100)] * 2, logger)
    assert degradations(summarize(r)) == ['residual_logger lost 80 of 80 measurements']


def test_counts_not_settled_while_the_logger_waits_or_has_not_taken_the_replays_count():
    for logger in (_logger(waiting=3), _logger(sent=False)):
        r = Reports()
        _run(r, [_feedforward(100, 100)] * 2, logger)
        assert not r.settled()
        assert describe(summarize(r))[-1].startswith('(the counts had not settled')
    r = Reports()
    _run(r, [_feedforward(90, 90), _feedforward(100, 100)], _logger())
    assert not r.settled()  # still counting
