"""config/gimbal_friction.yaml lists every node setting with its default (under /**)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from gimbal_friction.estimation.estimator import EstimatorSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.nodes.estimator import NodeSettings as EstimatorNode
from gimbal_friction.nodes.feedforward import NodeSettings as FeedforwardNode
from gimbal_friction.nodes.residual_logger import LoggerSettings

ROOT = Path(__file__).resolve().parents[2]
NODES = {'friction_feedforward': (FeedforwardSettings, FeedforwardNode),
         'friction_estimator': (EstimatorSettings, EstimatorNode),
         'residual_logger': (LoggerSettings,)}


@pytest.mark.parametrize('node', list(NODES))
def test_node_section_documents_every_setting_with_its_default(node):
    doc = yaml.safe_load((ROOT / 'config' / 'gimbal_friction.yaml').read_text())
    assert list(doc) == ['/**']  # node sections would beat a later -p override (rcl), so none are shipped
    params = doc['/**']['ros__parameters']
    fields = {f.name: f.default for cls in NODES[node] for f in dataclasses.fields(cls)}
    assert set(fields) <= set(params)
    for name, default in fields.items():
        assert params[name] == pytest.approx(default) if isinstance(default, float) else params[name] == default
    readme = (ROOT / 'README.md').read_text() + (ROOT / 'docs' / 'ros.md').read_text()  # (the parameter reference)
    missing = [n for n in fields if f'`{n}`' not in readme]
    assert missing == []
