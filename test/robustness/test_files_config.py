"""Configuration and shipped files: YAML and binary parameter files give one line; package.xml names only real
rosdep keys; the launch file's docstring names only what exists; the Foxglove layout picks joints by name."""

from __future__ import annotations

import ast
import importlib.util
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from gimbal_friction.config.loader import axis_names, load_parameters
from gimbal_friction.recording import topics
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS, RESIDUAL_FIELDS_V1

ROOT = Path(__file__).resolve().parents[2]


def test_yaml_errors_are_one_line_with_the_place(tmp_path: Path, rb) -> None:
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    model: [1, 2\n    axes: [x]\n')
    line = rb.refused(rb.run('model', '--config', str(bad)), 'model')
    assert 'not valid YAML: line 4, column 9' in line and str(bad) in line
    tabs = tmp_path / 'tabs.yaml'
    tabs.write_text('a:\n\tb: 1\n')
    assert "found character '\\t'" in rb.refused(rb.run('model', '--config', str(tabs)), 'model')


def test_report_compare_with_a_file_that_is_no_parameter_file(tmp_path: Path, rb) -> None:
    binary = tmp_path / 'refit.yaml'
    binary.write_bytes(bytes(range(256)) * 4)
    line = rb.refused(rb.run('report', '--compare', str(binary), '--out', str(tmp_path / 'r')), 'report')
    assert 'not UTF-8 text' in line
    listing = tmp_path / 'list.yaml'
    listing.write_text('- 1\n- 2\n')
    line = rb.refused(rb.run('report', '--compare', str(listing), '--out', str(tmp_path / 'r2')), 'report')
    assert 'must map node names' in line
    assert not (tmp_path / 'r').exists() and not (tmp_path / 'r2').exists()  # refused before drawing


#: rosdep keys checked against ros/rosdistro rosdep/base.yaml and rosdep/python.yaml @ 8468e88 (2026-08-22);
#: ``python3-mcap-pip`` and ``python3-mcap-ros2-support-pip`` are not keys (rosdep install failed on them)
ROSDEP_KEYS = {'python3-numpy', 'python3-scipy', 'python3-yaml', 'python3-matplotlib', 'python3-rosbags-pip',
               'mcap-ros2-support', 'python3-pytest', 'python3-hypothesis'}
#: ROS packages (resolved by rosdep from the distribution index)
ROS_PACKAGES = {'rclpy', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs', 'builtin_interfaces', 'rcl_interfaces',
                'lifecycle_msgs', 'launch', 'launch_ros'}


def test_package_xml_names_only_real_rosdep_keys() -> None:
    root = ET.parse(ROOT / 'package.xml').getroot()
    deps = [e.text for e in root if e.tag.endswith('depend')]
    unknown = [d for d in deps if d not in ROSDEP_KEYS | ROS_PACKAGES]
    assert not unknown, f'not rosdep keys: {unknown}'
    assert {'python3-rosbags-pip', 'mcap-ros2-support'} <= set(deps)  # rosbags; mcap (a dependency of the latter)
    requirements = (ROOT / 'requirements.txt').read_text()
    assert 'mcap==' in requirements and 'rosbags==' in requirements


def test_launch_docstring_names_what_exists() -> None:
    text = (ROOT / 'launch' / 'gimbal_friction.launch.py').read_text()
    doc = ast.get_docstring(ast.parse(text)) or ''
    modules = re.findall(r'python -m ([\w.]+)', doc)
    assert modules and all(importlib.util.find_spec(m) is not None for m in modules), modules
    scripts = set(re.findall(r"'([\w-]+) = gimbal_friction\.", (ROOT / 'setup.py').read_text()))
    named = set(re.findall(r'^\s+(friction_\w+|residual_logger|chamber_replay)\s', doc, re.MULTILINE))
    assert named and named <= scripts, named - scripts
    for path in re.findall(r'(config/[\w.]+)', doc):
        assert (ROOT / path).is_file(), path


def _paths(layout: dict) -> list[str]:
    return [p['value'] for panel in layout['configById'].values() for p in panel.get('paths', [])]


def test_foxglove_layout_picks_joints_by_name() -> None:
    layout = json.loads((ROOT / 'config' / 'foxglove_layout.json').read_text())
    paths = _paths(layout)
    assert paths
    joint_state_topics = [topics.JOINT_STATES, topics.MOTOR_CURRENT, topics.FEEDFORWARD, topics.MEASURED,
                          topics.RESIDUAL]
    for path in paths:
        # a JointState array or residual_detail data indexed by position is another joint on another robot
        assert not re.search(r'\.(position|velocity|effort|name|data)\[\d+\]', path), path
        assert not any(path.startswith(t + '.') for t in [*joint_state_topics, topics.RESIDUAL_DETAIL]), path
        if path.startswith('/studio_script/'):
            assert '$axis' in path, path  # one joint, chosen by the axis variable
    assert layout['globalVariables']['axis'] == axis_names(load_parameters())[0]
    scripts = layout['userNodes'].values()
    outputs = {re.search(r'export const output = "([^"]+)"', s['sourceCode']).group(1) for s in scripts}
    assert {p.split('{')[0].split('.')[0] for p in paths if p.startswith('/studio_script/')} <= outputs
    for script in scripts:
        inputs = json.loads(re.search(r'export const inputs = (\[[^\]]*\])', script['sourceCode']).group(1))
        assert set(inputs) <= {topics.JOINT_STATES, topics.MOTOR_CURRENT, topics.FEEDFORWARD, topics.MEASURED,
                               topics.RESIDUAL_DETAIL}


def test_foxglove_residual_script_follows_the_row_layouts() -> None:
    layout = json.loads((ROOT / 'config' / 'foxglove_layout.json').read_text())
    (source,) = [s['sourceCode'] for s in layout['userNodes'].values() if topics.RESIDUAL_DETAIL in s['sourceCode']]
    fields = dict(re.findall(r'(\w+): d\[(\d+)\]', source))
    for name, index in fields.items():
        assert RESIDUAL_FIELDS.index(name) == int(index) == RESIDUAL_FIELDS_V1.index(name), name
    assert f'd.length === {len(RESIDUAL_FIELDS)} ? d[{RESIDUAL_FIELDS.index("residual_nm")}]' in source
    assert f'd.length === {len(RESIDUAL_FIELDS_V1)} ? d[{RESIDUAL_FIELDS_V1.index("residual_nm")}]' in source
    for path in _paths(layout):
        match = re.match(r'/studio_script/residual_rows\{joint==\$axis\}\.(\w+)$', path)
        if match:
            assert match.group(1) in RESIDUAL_FIELDS, path
