"""The package's layers: each folder imports only folders below it, and the pure layers load no ROS or I/O library.

The order, bottom to top (each folder's ``__init__`` says the same in words)::

    common < physics < streams < feedforward, estimation < recording < refit, export, plots < sim < config
           < chamber < runs < nodes, cli < the public facades at the package root (controller, demo, core)

Every import counts, including the ones inside functions: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / 'gimbal_friction'

#: folder -> level; a module may import its own folder and any folder of a lower level
LEVELS = {
    'common': 0, 'physics': 1, 'streams': 2, 'feedforward': 3, 'estimation': 3, 'recording': 4,
    'refit': 5, 'export': 5, 'plots': 5, 'sim': 6, 'config': 7, 'chamber': 8, 'runs': 9, 'nodes': 10, 'cli': 10,
}
ROOT_FACADES = {'__init__', 'controller', 'demo', 'core'}

#: libraries a pure layer must not load: ROS, bags, logs and figures are the business of the layers above
IO_LIBRARIES = ('rclpy', 'rosbags', 'mcap', 'mcap_ros2', 'sqlite3', 'zstandard', 'lz4', 'matplotlib')
PURE = {'common': (*IO_LIBRARIES, 'yaml'), 'physics': (*IO_LIBRARIES, 'yaml'), 'streams': (*IO_LIBRARIES, 'yaml'),
        'feedforward': IO_LIBRARIES, 'estimation': (*IO_LIBRARIES, 'yaml'), 'sim': (*IO_LIBRARIES, 'yaml')}


def _modules() -> list[Path]:
    return sorted(p for p in PKG.rglob('*.py') if '__pycache__' not in p.parts)


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding='utf-8'))
    names: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
            if node.module == 'gimbal_friction':
                names += [f'gimbal_friction.{a.name}' for a in node.names]
    return names


def _folder(path: Path) -> str:
    rel = path.relative_to(PKG)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def test_every_folder_has_a_level():
    folders = {p.name for p in PKG.iterdir() if p.is_dir() and (p / '__init__.py').exists()}
    assert folders == set(LEVELS), 'a new folder needs its place in LEVELS (and a line in its __init__)'
    loose = {p.stem for p in PKG.glob('*.py')} - ROOT_FACADES
    assert loose == set(), f'modules loose at the package root: {sorted(loose)}'


def test_no_folder_imports_a_higher_one():
    offenders = []
    for path in _modules():
        here = _folder(path)
        if here in ROOT_FACADES:
            continue
        for name in _imports(path):
            parts = name.split('.')
            if parts[0] != 'gimbal_friction' or len(parts) < 2 or parts[1] == '__version__':
                continue
            there = parts[1]
            if there in ROOT_FACADES:
                offenders.append(f'{path.relative_to(PKG)} imports the facade {name}')
            elif there not in LEVELS:
                offenders.append(f'{path.relative_to(PKG)} imports unknown {name}')
            elif there != here and LEVELS[there] >= LEVELS[here]:
                offenders.append(f'{path.relative_to(PKG)} ({here}) imports {name} ({there})')
    assert offenders == []


@pytest.mark.parametrize('folder', sorted(PURE))
def test_pure_layer_names_no_io_library(folder):
    offenders = [f'{p.relative_to(PKG)}: {n}' for p in (PKG / folder).rglob('*.py') for n in _imports(p)
                 if n.split('.')[0] in PURE[folder]]
    assert offenders == []


def test_importing_the_pure_layers_loads_no_ros_or_io_module():
    modules = sorted('gimbal_friction.' + '.'.join(p.relative_to(PKG).with_suffix('').parts)
                     for f in PURE for p in (PKG / f).rglob('*.py') if p.stem != '__init__')
    forbidden = sorted({lib for libs in PURE.values() for lib in libs} - {'yaml'})
    code = (f'import importlib, sys\nfor m in {modules!r}: importlib.import_module(m)\n'
            f'bad = sorted(m for m in sys.modules if m.split(".")[0] in {forbidden!r})\n'
            'assert not bad, bad\nprint("pure")')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert 'pure' in out.stdout


@pytest.mark.slow
def test_the_command_line_loads_no_ros():
    code = ('import sys, gimbal_friction.cli.main as c; c.build_parser()\n'
            'bad = [m for m in sys.modules if m.startswith("rclpy")]\nassert not bad, bad\nprint("pure")')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert 'pure' in out.stdout
