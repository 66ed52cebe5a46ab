"""What the live nodes of a run counted, from their own ``/diagnostics``: the main job's account of its live run.

A probe collects every status the nodes publish (:class:`Reports`); :func:`summarize` reads the counters the nodes
keep (messages received and lost per topic, what ``chamber_replay`` sent, feedforwards published, samples accepted,
inputs refused, rows logged with and without a feedforward, and the reports in which ``friction_feedforward`` had
no fresh temperature); :func:`describe` says it in lines and :func:`degradations` names what made the live run
differ from ``replay`` of the same bag. Nothing here is recomputed from the data: every number is a node's own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from gimbal_friction.estimation.gating import INPUT_REASONS
from gimbal_friction.recording import topics
from gimbal_friction.streams.delivery import PUBLISHER_STATUS, lost_key, read_publisher_values, received_key, sent_key

#: the status names the nodes publish (docs/ros.md, Diagnostics)
FEEDFORWARD_PREFIX = 'gimbal_friction/feedforward/'
FEEDFORWARD_LEARNING = 'gimbal_friction/feedforward/learning'
ESTIMATOR_INPUTS = 'gimbal_friction/estimator'
ESTIMATOR_PREFIX = 'gimbal_friction/estimator/'
LOGGER = 'gimbal_friction/residual_logger'
#: the feedforward's ``temperature_source`` while its temperature is fresh
FRESH_SOURCE = 'measured'
#: what the messages of each topic are called in the account
NOUNS = {topics.JOINT_STATES: 'joint states', topics.MOTOR_CURRENT: 'currents', topics.TEMPERATURE: 'temperatures',
         topics.FEEDFORWARD: 'feedforwards', topics.MEASURED: 'measurements',
         topics.MEASURED_DETAIL: 'measurement details', topics.DIAGNOSTICS: 'diagnostics'}
#: the topics each node subscribes (a topic of these that was sent and that the node never received is missing
#: whole)
SUBSCRIBES = {'friction_feedforward': (topics.TEMPERATURE, topics.JOINT_STATES, topics.MEASURED_DETAIL),
              'friction_estimator': (topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT),
              'residual_logger': (topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT, topics.FEEDFORWARD,
                                  topics.MEASURED, topics.MEASURED_DETAIL)}
#: the values that tell whether a node's counts have settled (besides received/lost/sent per topic)
_SETTLING = ('published', 'accepted', 'residuals_logged', 'paired_with_feedforward', 'no_feedforward',
             'waiting_for_feedforward', 'messages_logged')


_RECEIVED, _LOST, _SENT = received_key(''), lost_key(''), sent_key('')


def _counts(values: Mapping[str, str]) -> dict[str, str]:
    """The counts of a status that settle when the data stops (not the diagnostics the nodes keep receiving)."""
    return {k: v for k, v in values.items()
            if (k.startswith((_RECEIVED, _LOST, _SENT)) and not k.endswith(topics.DIAGNOSTICS)) or k in _SETTLING}


@dataclass
class Reports:
    """The statuses seen on ``/diagnostics`` (name -> values as text), the one before the latest of each, how many
    reports each status made, and how many of ``friction_feedforward``'s said its temperature was not fresh, by
    the source it used instead."""

    latest: dict[str, dict[str, str]] = field(default_factory=dict)
    previous: dict[str, dict[str, str]] = field(default_factory=dict)
    reports: dict[str, int] = field(default_factory=dict)
    #: per feedforward status: reports made while it published, and of those the ones without a fresh
    #: temperature, by the temperature source used instead
    publishing: dict[str, int] = field(default_factory=dict)
    stale: dict[str, dict[str, int]] = field(default_factory=dict)

    def add(self, name: str, values: Mapping[str, str]) -> None:
        """One status ``name`` with its ``values`` (key -> text, untrusted)."""
        before = self.latest.get(name)
        if before is not None:
            self.previous[name] = before
        self.latest[name] = dict(values)
        self.reports[name] = self.reports.get(name, 0) + 1
        if _is_feedforward_joint(name):
            # only a report of a period in which the feedforward published says what its outputs used (before
            # the first temperature and after the last joint state there is nothing to be fresh for)
            published = _int(values.get('published'))
            if published is None or published <= (_int((before or {}).get('published')) or 0):
                return
            self.publishing[name] = self.publishing.get(name, 0) + 1
            source = str(values.get('temperature_source', FRESH_SOURCE))
            if source != FRESH_SOURCE:
                by_source = self.stale.setdefault(name, {})
                by_source[source] = by_source.get(source, 0) + 1

    def settled(self) -> bool:
        """Every node status has reported its counts twice alike, the logger waits for no feedforward, and the
        logger has taken ``chamber_replay``'s count of what it sent (when the replay said it)."""
        names = [n for n in self.latest if n != PUBLISHER_STATUS and (n in (LOGGER, ESTIMATOR_INPUTS)
                                                                      or _is_feedforward_joint(n))]
        if not names or any(_counts(self.latest[n]) != _counts(self.previous.get(n, {})) for n in names):
            return False
        logger = self.latest.get(LOGGER, {})
        if logger.get('waiting_for_feedforward', '0') != '0':
            return False
        _, sent = read_publisher_values(self.latest.get(PUBLISHER_STATUS, {}))
        return all(sent_key(s.topic) in logger for s in sent if s.gid is not None and received_key(s.topic) in logger)


def _is_feedforward_joint(name: str) -> bool:
    return name.startswith(FEEDFORWARD_PREFIX) and name != FEEDFORWARD_LEARNING


def _int(text: Any) -> int | None:
    try:
        return int(str(text))
    except ValueError:
        return None


def _transport(values: Mapping[str, str]) -> dict[str, dict[str, int | None]]:
    """``received: <topic>`` / ``lost: <topic>`` (None: unknown) of a status, per topic."""
    out: dict[str, dict[str, int | None]] = {}
    for key, text in values.items():
        for kind, prefix in (('received', _RECEIVED), ('lost', _LOST)):
            if key.startswith(prefix):
                out.setdefault(key[len(prefix):], {})[kind] = _int(text)
    return out


def _prefixed(values: Mapping[str, str], prefix: str) -> dict[str, int]:
    return {k[len(prefix):]: n for k, v in values.items() if k.startswith(prefix) and (n := _int(v)) is not None}


def summarize(reports: Reports) -> dict[str, Any]:
    """What the live nodes counted (JSON-able): per node the transport (``received``/``lost`` per topic) and its own
    counters; ``chamber_replay``'s ``sent`` per topic; ``sent``: what was sent on each topic by the counters of its
    publisher (the replay's, the feedforwards published, the samples the estimator accepted); ``settled`` (see
    :meth:`Reports.settled`)."""
    latest = reports.latest
    state, sent = read_publisher_values(latest.get(PUBLISHER_STATUS, {}))
    out: dict[str, Any] = {'settled': reports.settled(),
                           'chamber_replay': {'state': state or 'not seen', 'sent': {s.topic: s.sent for s in sent}}}
    ff_names = sorted(n for n in latest if _is_feedforward_joint(n))
    if ff_names:
        first = latest[ff_names[0]]
        refused: dict[str, int] = {}
        for name in ff_names:  # the rejections are the node's, repeated in every joint's status
            refused = {**refused, **_prefixed(latest[name], 'rejected_temperature: '),
                       **_prefixed(latest[name], 'rejected_joint_state: '),
                       **_prefixed(latest[name], 'rejected_reference: ')}
        stale: dict[str, int] = {}
        for name in ff_names:
            for source, n in reports.stale.get(name, {}).items():
                stale[source] = max(stale.get(source, 0), n)
        out['friction_feedforward'] = {
            'transport': _transport(first), 'published': _int(first.get('published')), 'refused': refused,
            'reports': max(reports.publishing.get(n, 0) for n in ff_names),
            'reports_without_fresh_temperature': max(sum(reports.stale.get(n, {}).values()) for n in ff_names),
            'used_instead': stale, 'errors': _prefixed(first, 'callback error: ')}
    joints = sorted(n for n in latest if n.startswith(ESTIMATOR_PREFIX) and '/statistics' not in n)
    if ESTIMATOR_INPUTS in latest or joints:
        inputs = latest.get(ESTIMATOR_INPUTS, {})
        not_accepted: dict[str, int] = {}
        for name in joints:
            for reason, n in _prefixed(latest[name], 'rejected: ').items():
                not_accepted[reason] = not_accepted.get(reason, 0) + n
        out['friction_estimator'] = {
            'transport': _transport(inputs),
            'accepted': sum(_int(latest[n].get('accepted')) or 0 for n in joints),
            'not_accepted': not_accepted,
            'refused': {r: n for r, n in not_accepted.items() if r in INPUT_REASONS and n},
            'errors': _prefixed(inputs, 'callback error: ')}
    if LOGGER in latest:
        v = latest[LOGGER]
        out['residual_logger'] = {
            'transport': _transport(v), 'sent': _prefixed(v, _SENT),
            'residuals_logged': _int(v.get('residuals_logged')),
            'paired_with_feedforward': _int(v.get('paired_with_feedforward')),
            'no_feedforward': _int(v.get('no_feedforward')), 'dropped': _int(v.get('dropped')),
            'refused': {r: n for r, n in _prefixed(v, 'refused: ').items() if n},
            'errors': _prefixed(v, 'callback error: ')}
    # what was sent on each topic, by the counters of its publisher in the run: the replay's inputs, the
    # feedforward's outputs, the estimator's samples (one measured and one measured_detail message each)
    sent_all: dict[str, int] = dict(out['chamber_replay']['sent'])
    if (published := out.get('friction_feedforward', {}).get('published')) is not None:
        sent_all[topics.FEEDFORWARD] = published
    if 'friction_estimator' in out:
        sent_all[topics.MEASURED] = sent_all[topics.MEASURED_DETAIL] = out['friction_estimator']['accepted']
    out['sent'] = sent_all
    return out


def _noun(topic: str) -> str:
    return NOUNS.get(topic, topic)


def _missing(summary: Mapping[str, Any], node: str) -> dict[str, int]:
    """Per topic, the messages that did not reach ``node``: what the publisher sent minus what the node received
    where the publisher's count is known (``summary['sent']``), else what the node counted lost."""
    sent = summary['sent']
    transport = {**{t: {'received': 0, 'lost': 0} for t in SUBSCRIBES.get(node, ()) if t in sent},
                 **summary[node]['transport']}
    out = {}
    for topic, t in transport.items():
        if topic == topics.DIAGNOSTICS:
            continue
        received, lost = t.get('received'), t.get('lost')
        n = (sent[topic] - (received or 0)) if topic in sent else (lost or 0)
        if n > 0:
            out[topic] = n
    return out


def _transport_text(summary: Mapping[str, Any], node: str) -> str:
    sent = summary['sent']
    transport = {**{t: {'received': 0, 'lost': 0} for t in SUBSCRIBES.get(node, ()) if t in sent},
                 **summary[node]['transport']}
    parts = []
    for topic, t in sorted(transport.items()):
        if topic == topics.DIAGNOSTICS:
            continue
        lost = 'unknown' if t.get('lost') is None else t['lost']
        of = f' of {sent[topic]}' if topic in sent else ''
        parts.append(f'{t.get("received")}{of} {_noun(topic)} (lost {lost})')
    return 'received ' + ', '.join(parts)


def _reasons(counts: Mapping[str, int]) -> str:
    return ', '.join(f'{r} {n}' for r, n in sorted(counts.items())) or 'none'


def describe(summary: Mapping[str, Any]) -> list[str]:
    """One line per node: what it counted."""
    lines = []
    sent = summary['chamber_replay']['sent']
    if sent:
        lines.append('chamber_replay        sent ' + ', '.join(f'{n} {_noun(t)}' for t, n in sent.items()))
    if 'friction_feedforward' in summary:
        f = summary['friction_feedforward']
        stale = (f'no fresh temperature in {f["reports_without_fresh_temperature"]} of {f["reports"]} reports '
                 'while publishing'
                 + (f' (used: {_reasons(f["used_instead"])})' if f['used_instead'] else ''))
        lines.append(f'friction_feedforward  {_transport_text(summary, "friction_feedforward")}; published '
                     f'{f["published"]} feedforwards; refused: {_reasons(f["refused"])}; {stale}')
    if 'friction_estimator' in summary:
        e = summary['friction_estimator']
        lines.append(f'friction_estimator    {_transport_text(summary, "friction_estimator")}; accepted '
                     f'{e["accepted"]} samples; refused: {_reasons(e["refused"])}; not in steady state: '
                     f'{_reasons({r: n for r, n in e["not_accepted"].items() if r not in INPUT_REASONS})}')
    if 'residual_logger' in summary:
        g = summary['residual_logger']
        lines.append(f'residual_logger       {_transport_text(summary, "residual_logger")}; logged '
                     f'{g["residuals_logged"]} rows: {g["paired_with_feedforward"]} with the feedforward, '
                     f'{g["no_feedforward"]} without; refused: {_reasons(g["refused"])}')
    if not summary['settled']:
        lines.append('(the counts had not settled when the nodes were stopped: the last reports are shown)')
    return lines


def degradations(summary: Mapping[str, Any]) -> list[str]:
    """What made the live run differ from ``replay`` of the same bag, one phrase per node (empty: nothing)."""
    out = []
    for node in ('friction_feedforward', 'friction_estimator', 'residual_logger'):
        if node not in summary:
            continue
        s = summary[node]
        sent = summary['sent']
        lost = [f'{n}{f" of {sent[t]}" if t in sent else ""} {_noun(t)}'
                for t, n in sorted(_missing(summary, node).items())]
        said = [f'lost {", ".join(lost)}'] if lost else []
        if s.get('refused'):
            said.append(f'refused {sum(s["refused"].values())} inputs ({_reasons(s["refused"])})')
        if node == 'friction_feedforward' and s['reports_without_fresh_temperature']:
            said.append(f'had no fresh temperature in {s["reports_without_fresh_temperature"]} of {s["reports"]} '
                        f'reports while publishing (used: {_reasons(s["used_instead"])})')
        if node == 'residual_logger' and s.get('no_feedforward'):
            said.append(f'logged {s["no_feedforward"]} measurements without a feedforward')
        if node == 'residual_logger' and s.get('dropped'):
            said.append(f'could not write {s["dropped"]} messages')
        if s.get('errors'):
            said.append(f'had {sum(s["errors"].values())} callback errors')
        if said:
            out.append(f'{node} {", ".join(said)}')
    return out


def verdict(summary: Mapping[str, Any]) -> str:
    """One line: whether the live run degraded, and what that means for the report's table."""
    found = degradations(summary)
    if found:
        return ('the live run degraded: ' + '; '.join(found) + ": the report's 'model' column (the feedforward as "
                'published live) may differ from replay of the same bag')
    return ("the live run did not degrade: every node received every message sent, no input was refused and the "
            "feedforward always had a fresh temperature: the report's 'model' column is what replay gives")
