"""The feedforward inside your own controller process: no DDS hop, the same object and rules as the node.

:func:`load_feedforward` builds :class:`~gimbal_friction.feedforward.rule.Feedforward` — the very object the
``friction_feedforward`` node runs — from the same parameter files the nodes load (the packaged defaults, then your
files layered key by key, like repeated ``--params-file``; node settings from the ``/**`` and
``friction_feedforward`` sections). Every rule is the node's: temperature validation and the stale policy (on the
times you pass), the smooth sign, the per-direction factors, the clamp.

A controller loop (Python, e.g. a custom rclpy control node or a test-bench script)::

    from gimbal_friction.controller import load_feedforward
    ff = load_feedforward('config/gimbal_friction.yaml', 'refit.yaml')
    ...
    ff.update_temperature(bearing_temperature_c, time_s=t)           # whenever a temperature arrives
    u = rate_pi(error) + ff.torque_nm('elevation', joint_velocity_rad_s, time_s=t)   # every tick, ~1 µs

``joint_velocity_rad_s`` is the rate of the gimbal relative to the base (the resolver's), or the reference joint
rate the controller commands; never the inertial LOS rate of the gyro. Times are seconds on any clock, as long as
temperature and tick times share it.

A learned correction (``refit --correction-out``; :mod:`gimbal_friction.feedforward.correction`) is added to the
model friction when its file is given: ``load_feedforward('refit.yaml', correction='refit.correction.yaml')``, then
pass the joint position (the reference position with a reference velocity) for its position map:
``ff.torque_nm('elevation', v, time_s=t, position_rad=p)``. A file learned against other parameters, or corrupt, is
refused with one line (:class:`~gimbal_friction.feedforward.correction.CorrectionError`), and so is one whose figures
the model cannot give (a mean |model| the model does not reach: it would let the file move the output further than
learning could); ``ff.set_correction(None)`` returns to the pure model at run time.

The model's validity range (:mod:`gimbal_friction.physics.validity`, −40…+60 °C with the paper's parameters) holds
here as in the node: ``ff.model_ranges`` gives each joint's table range, a credible temperature outside it is used at
the range's edge and counted in ``ff.counters.temperature_clamped``.

>>> ff = load_feedforward()
>>> ff.update_temperature(-40.0, time_s=100.0)
>>> round(ff.torque_nm('elevation', 0.0349066, time_s=100.001) * 1e3, 3)   # N*mm at 1/3 rpm, -40 degC
3.143
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from gimbal_friction.common.settings import settings_from_parameters
from gimbal_friction.config.loader import all_axis_params, check_config_files, load_parameters
from gimbal_friction.feedforward.correction import Correction, CorrectionError, model_identity
from gimbal_friction.feedforward.correction import load as load_correction
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.streams.inputs import unconfigured_joints

__all__ = ['Correction', 'CorrectionError', 'Feedforward', 'FeedforwardSettings', 'load_feedforward']


def load_feedforward(*param_files: str | Path, node_name: str = 'friction_feedforward',
                     axes: Iterable[str] | None = None, correction: str | Path | None = None) -> Feedforward:
    """The feedforward object of the node ``node_name``, built from parameter files layered over the packaged
    defaults.

    Parameters
    ----------
    *param_files : str or Path
        ROS 2 parameter files (``config/gimbal_friction.yaml``, a ``refit`` output, ...), layered in order.
    node_name : str
        Whose node section applies besides ``/**`` (default the feedforward node's).
    axes : iterable of str, optional
        Only these configured joints (default: every configured axis).
    correction : str or Path, optional
        A learned correction file (``refit --correction-out``), added to the model friction; it must have been
        learned against the parameters these files configure (all configured axes).

    Raises
    ------
    ConfigError
        A missing or invalid file or value (named), or a joint that is not configured.
    ModelDomainError
        Parameters for which the model cannot be evaluated over the temperature range.
    CorrectionError
        The correction file is missing, corrupt, or learned against other joints or parameters (one line).
    """
    paths = [Path(p) for p in param_files]
    check_config_files(paths)   # a misspelt name is refused, not silently ignored
    configured = all_axis_params(load_parameters(paths))
    whole = model_identity(configured)   # a correction is learned against every configured axis
    if axes is not None:
        wanted = list(axes)
        refused = unconfigured_joints(wanted, list(configured))
        if refused:
            from gimbal_friction.common.errors import ConfigError
            raise ConfigError('axes', refused)
        configured = {a: configured[a] for a in wanted}
    settings = settings_from_parameters(FeedforwardSettings, load_parameters(paths, node_name=node_name))
    ff = Feedforward(configured, settings)
    if correction is not None:
        # (every figure of the file checked against the model it was learned against: the whole configuration)
        whole_model = all_axis_params(load_parameters(paths))
        ff.set_correction(load_correction(correction, expected=whole, model=whole_model), expected=whole)
    return ff
