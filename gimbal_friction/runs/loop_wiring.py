"""The closed loop's wiring: which nodes run, under which names, with which parameter files, parameters and remappings.

One source of truth for ``gimbal-friction loop-study --live`` (:mod:`gimbal_friction.runs.loop_live`, which starts
the nodes as processes with :meth:`NodeSpec.ros_args`) and ``ros2 launch gimbal_friction closed_loop.launch.py``
(which hands the same :class:`NodeSpec` values to ``launch_ros``). Pure Python: no rclpy, no launch.

The loop: ``gimbal_sim`` (a simulated gimbal axis with its seeker controller) publishes the suite's input topics
and adds the feedforward it receives to its motor command; ``friction_feedforward`` answers its joint states,
``friction_estimator`` (method ``observer``: while the gimbal works) estimates friction from them and
``residual_logger`` logs both. Every node reads the parameter files of :func:`write_parameter_files`, in order:
the packaged defaults, the study's axis (its ``model.*`` and ``axis.<joint>.*`` values, that axis only) and the
study's own (the estimator's method and settings, the feedforward's settings, the simulator configuration);
the topics are the suite's defaults, but one: ``friction_feedforward``'s loop-error input ``/gimbal/loop_error`` is
remapped onto ``gimbal_sim``'s ``/gimbal_sim/los_error`` (:data:`LOOP_ERROR_REMAP`: the loop's error judges the
learned correction), which keeps its name for every other reader.

>>> spec = NodeSpec('residual_logger', 'residual_logger', ('a.yaml',), {'output_dir': '/tmp/r', 'rate': 2.0})
>>> spec.ros_args()
['--ros-args', '--params-file', 'a.yaml', '-p', 'output_dir:=/tmp/r', '-p', 'rate:=2.0']
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from gimbal_friction.runs.loop_study import StudyInputs

#: the suite's nodes in the loop, in start order
LOOP_NODES = ('friction_feedforward', 'friction_estimator', 'residual_logger')
#: the simulator's node (and executable) name
SIM_NODE = 'gimbal_sim'
#: the defaults of ``loop-study --live`` (and of the launch file): plateau [degC], profile, real-time factor [-],
#: joint states every N controller ticks [-]
DEFAULT_TEMPERATURE_C = -40.0
DEFAULT_PROFILE = 'tracking'
DEFAULT_REALTIME_FACTOR = 1.0
DEFAULT_PUBLISH_EVERY_TICKS = 2
#: the estimator's method in the loop
ESTIMATOR_METHOD = 'observer'
#: gimbal_sim waits for this many subscribers of /joint_states (the three nodes) before it starts
WAIT_FOR_SUBSCRIBERS = len(LOOP_NODES)

ParameterValue = bool | int | float | str
#: the feedforward's loop-error input wired to the simulated seeker's LOS error (``(from, to)``)
LOOP_ERROR_REMAP = ('/gimbal/loop_error', '/gimbal_sim/los_error')


class NodeSpec(NamedTuple):
    """One node of the loop: its node name, executable, parameter files (in order), parameters set after the files
    and topic remappings (``(from, to)``)."""

    name: str
    executable: str
    parameter_files: tuple[str, ...]
    parameters: Mapping[str, ParameterValue]
    remappings: tuple[tuple[str, str], ...] = ()

    def ros_args(self) -> list[str]:
        """The node's command-line arguments: ``--ros-args``, the files, ``-p name:=value``, ``-r from:=to``."""
        args = ['--ros-args']
        for path in self.parameter_files:
            args += ['--params-file', path]
        for key, value in self.parameters.items():
            args += ['-p', f'{key}:={_arg_text(value)}']
        for src, dst in self.remappings:
            args += ['-r', f'{src}:={dst}']
        return args


def _arg_text(value: ParameterValue) -> str:
    """A parameter value as ``-p`` reads it (YAML): booleans lower case, floats with their decimal point."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    return str(value)


def write_parameter_files(inputs: StudyInputs, folder: Path) -> list[Path]:
    """Write the loop's parameter files into ``folder`` and return them in load order: the packaged defaults, the
    study's axis (``axes`` = that axis only, its ``model.*`` and ``axis.<joint>.*`` values), the study's own (under
    ``/**`` the estimator in observer mode with its settings and the feedforward's settings; the ``gimbal_sim``
    section with the simulator configuration the study ran with, latency and seed included)."""
    import yaml

    from gimbal_friction.config.loader import render_parameter_file
    from gimbal_friction.runs.supervisor import packaged_params_file
    folder.mkdir(parents=True, exist_ok=True)
    with packaged_params_file() as packaged:
        text = Path(packaged).read_text(encoding='utf-8')
    files = [folder / 'packaged.yaml']
    files[0].write_text(text, encoding='utf-8')
    axis_file = folder / 'axis.yaml'
    axis_file.write_text(render_parameter_file(axes_overrides={inputs.axis_name: inputs.axis.to_mapping()},
                                               axes=[inputs.axis_name]), encoding='utf-8')
    files.append(axis_file)
    ff = inputs.feedforward
    node = {'method': ESTIMATOR_METHOD, **{k: getattr(ff.settings, k) for k in ff.settings.__dataclass_fields__},
            'velocity_source': ff.velocity_source}
    est = inputs.estimator
    node.update({k: getattr(est, k) for k in est.__dataclass_fields__ if k != 'method'})
    study = folder / 'study.yaml'
    study.write_text(yaml.safe_dump({'/**': {'ros__parameters': node},
                                     SIM_NODE: {'ros__parameters': inputs.sim.to_mapping()}},
                                    sort_keys=False), encoding='utf-8')
    files.append(study)
    return files


def loop_nodes(parameter_files: Sequence[str | Path], residual_dir: str | Path,
               names: Sequence[str] = LOOP_NODES) -> list[NodeSpec]:
    """The suite's nodes of the loop (``names``, in start order): each reads ``parameter_files``; the residual
    logger writes into ``residual_dir``."""
    files = tuple(str(f) for f in parameter_files)
    unknown = [n for n in names if n not in LOOP_NODES]
    if unknown:
        msg = f'not a node of the loop: {", ".join(unknown)} (the loop has {", ".join(LOOP_NODES)})'
        raise ValueError(msg)
    return [NodeSpec(name, name, files, {'output_dir': str(residual_dir)} if name == 'residual_logger' else {},
                     (LOOP_ERROR_REMAP,) if name == 'friction_feedforward' else ())
            for name in names]


class SimRun(NamedTuple):
    """One ``gimbal_sim`` run of the loop: with the feedforward (``use_feedforward``: added to the motor command and
    waited for before the run starts) or without, the plateau [degC], the profile and its duration [s],
    the real-time factor [-], joint states every ``publish_every_ticks`` controller ticks, the run's record
    (``record_path``; empty: none), and whether the process ends after the run."""

    duration_s: float
    use_feedforward: bool = True
    temperature_c: float = DEFAULT_TEMPERATURE_C
    profile: str = DEFAULT_PROFILE
    realtime_factor: float = DEFAULT_REALTIME_FACTOR
    publish_every_ticks: int = DEFAULT_PUBLISH_EVERY_TICKS
    record_path: str = ''
    exit_when_done: bool = True

    def parameters(self) -> dict[str, ParameterValue]:
        """The parameters ``gimbal_sim`` gets after its files."""
        use = bool(self.use_feedforward)
        return {'environment_temperature_c': float(self.temperature_c), 'profile': self.profile,
                'duration_s': float(self.duration_s), 'exit_when_done': bool(self.exit_when_done),
                'use_feedforward': use, 'wait_for_subscribers': WAIT_FOR_SUBSCRIBERS, 'wait_for_feedforward': use,
                'realtime_factor': float(self.realtime_factor), 'record_path': str(self.record_path),
                'publish_every_ticks': int(self.publish_every_ticks)}


def sim_node(parameter_files: Sequence[str | Path], run: SimRun) -> NodeSpec:
    """``gimbal_sim`` with ``parameter_files`` and the parameters of ``run``."""
    return NodeSpec(SIM_NODE, SIM_NODE, tuple(str(f) for f in parameter_files), run.parameters())


def closed_loop(parameter_files: Sequence[str | Path], residual_dir: str | Path, run: SimRun) -> list[NodeSpec]:
    """The whole loop: the suite's three nodes (:func:`loop_nodes`), then ``gimbal_sim`` (:func:`sim_node`)."""
    return [*loop_nodes(parameter_files, residual_dir), sim_node(parameter_files, run)]
