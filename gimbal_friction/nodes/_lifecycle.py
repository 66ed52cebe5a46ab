"""Managed (lifecycle) nodes: the state machine around each node's one library object.

One job in one module: the lifecycle transitions shared by ``friction_feedforward``, ``friction_estimator`` and
``residual_logger`` (:class:`ManagedNode`); each node says what its own configure, activate, deactivate and cleanup
do (:meth:`ManagedNode.configure_node`, :meth:`~ManagedNode.start_output`, :meth:`~ManagedNode.stop_output`,
:meth:`~ManagedNode.release_node`).

The states and transitions are ROS 2's (``rclpy.lifecycle``, the standard ``/<node>/change_state`` and
``/<node>/get_state`` services of ``lifecycle_msgs``):

- construction declares the parameters (:meth:`ManagedNode.parameter_steps`), so an unconfigured node can be
  listed, described and set like any node.
- *configure* (unconfigured → inactive) reads the parameters, validates them and the files they name,
  and builds the node's objects, subscriptions, publishers and timers. A refusal (an invalid parameter, a model
  that does not build) is FAILURE: the reason is logged and published on ``/diagnostics``, everything configure
  had made is released and the node stays unconfigured.
- *activate* (inactive → active) starts the output: the node's publishers (``LifecyclePublisher``) publish only
  while active.
- *deactivate* (active → inactive) stops it: the node's own stop (the feedforward's zero per joint, the learned
  correction saved, the residual log's current file closed), then its publishers publish nothing.
- *cleanup* (inactive → unconfigured) releases every subscription, publisher and timer configure made (the
  parameters stay declared, with their values: the next configure reads them again).
- *shutdown* (from any primary state → finalized) deactivates and cleans up as needed.
- An unexpected exception in a transition is ERROR: the node goes through error processing (the reason logged and
  on ``/diagnostics``, everything released) back to unconfigured.

``autostart`` (bool, default true) configures and activates the node at start-up, so ``ros2 run`` brings it up
active as before; a refusal then stops the process with the reason (exit code 1). With ``autostart:=false`` the
node waits, unconfigured, for a lifecycle manager (nav2's ``lifecycle_manager``, ``ros2 lifecycle set``).
While unconfigured, a parameter may be set to any value of its type: configure validates it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.duration import Duration
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.config.loader import AUTOSTART_DESCRIPTION
from gimbal_friction.nodes._common import ERROR, diagnostic_array, status
from gimbal_friction.recording import topics

#: the primary states (lifecycle_msgs/msg/State labels)
UNCONFIGURED, INACTIVE, ACTIVE, FINALIZED = 'unconfigured', 'inactive', 'active', 'finalized'

#: a failed transition's status is published again this often [s] until a transition succeeds (a diagnostics
#: aggregator or a late `ros2 topic echo /diagnostics` sees it)
REPEAT_PERIOD_S = 1.0

#: at most this long [s, wall clock] a release waits for the subscribers to acknowledge what was published last
RELEASE_ACK_S = 1.0

SUCCESS, FAILURE, ERROR_RETURN = (TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE,
                                  TransitionCallbackReturn.ERROR)


def is_refusal(err: BaseException) -> bool:
    """An exception that refuses a configuration (FAILURE: the node's own words, or rclpy's refusal of a parameter
    value) rather than a bug (ERROR)."""
    return isinstance(err, GimbalFrictionError) or (type(err).__module__.startswith('rclpy')
                                                   and 'Parameter' in type(err).__name__)


class ManagedNode(LifecycleNode):
    """A node of the suite as a lifecycle node: the transitions call the node's hooks, never raise, and keep
    :attr:`lifecycle_state` (the primary state's label) for the diagnostics.

    Parameters
    ----------
    name : str
        The node's name.
    **kwargs
        rclpy.node.Node's (``context``, ``parameter_overrides``, ...).

    Raises
    ------
    GimbalFrictionError
        With ``autostart`` (the default), the reason the node refused to configure (what ``run_node`` reports as
        the one line of a failed start).
    """

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.lifecycle_state = UNCONFIGURED
        #: the reason of the last failed transition (None after a successful one)
        self.lifecycle_error: str | None = None
        self._last_exception: BaseException | None = None
        # the lifecycle's own /diagnostics publisher (a plain one: it reports a refusal while not active)
        self._lifecycle_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self._lifecycle_status: Any = None   #: the failed transition's status, repeated while the failure stands
        self._lifecycle_timer = self.create_timer(REPEAT_PERIOD_S, self._repeat_status)
        self.autostart = bool(self.declare_parameter('autostart', True, ParameterDescriptor(
            name='autostart', type=Parameter.Type.BOOL.value, description=AUTOSTART_DESCRIPTION,
            read_only=True)).value)
        self._declare_parameters()
        self._own = self._entities()
        self._starting = self.autostart   #: a refusal is raised to the caller, which reports it (not logged too)
        if self.autostart:
            for step in (self.trigger_configure, self.trigger_activate):
                ok = step() == SUCCESS
                if not ok:
                    self._starting = False
                    err = self._last_exception
                    if err is not None and is_refusal(err):
                        raise err
                    raise GimbalFrictionError(f'{name}: {self.lifecycle_error or "cannot start"}')
        self._starting = False

    def _declare_parameters(self) -> None:
        """Declare the node's parameters at construction, as nav2's nodes do: ``ros2 param list / get / set /
        describe`` work on an unconfigured node (``autostart:=false``), and the next configure reads what was set.
        A step that refuses (a value given at start-up of the wrong type or outside its range) is left undeclared
        here: configure declares it again and fails with the reason, as a lifecycle manager expects."""
        for step in self.parameter_steps():
            try:
                step()
            except Exception as err:  # (configure repeats the step and reports it: FAILURE or ERROR)
                self.get_logger().debug(f'parameters declared by configure: {type(err).__name__}: {err}')

    # ------------------------------------------------------------------ the node's hooks
    def parameter_steps(self) -> list[Callable[[], object]]:
        """The declarations of the node's parameters, each a step that may refuse alone (configure makes the same
        calls: a parameter already declared keeps its value)."""
        return []

    def configure_node(self) -> None:
        """Read the parameters (declaring any a construction step left undeclared), validate them, build everything
        (raises to refuse)."""

    def start_output(self) -> None:
        """On activate, after the publishers are enabled."""

    def stop_output(self) -> None:
        """On deactivate (and shutdown from active), before the publishers are disabled."""

    def release_node(self) -> None:
        """On cleanup (and shutdown, error): release what configure made besides ROS entities (files, threads)."""

    # ------------------------------------------------------------------ state
    @property
    def configured(self) -> bool:
        """Inactive or active: the node's objects exist and its parameters are live."""
        return self.lifecycle_state in (INACTIVE, ACTIVE)

    @property
    def active(self) -> bool:
        return self.lifecycle_state == ACTIVE

    def _entities(self) -> set[Any]:
        return {*self.publishers, *self.subscriptions, *self.timers, *self.clients, *self.services}

    def _release(self) -> None:
        """The node's own release, then every ROS entity made since construction destroyed: a publisher once what it
        published last has been acknowledged (at most :data:`RELEASE_ACK_S` for them all), so the deactivation's
        last messages (the feedforward's zero, the estimator's waiting samples) reach their subscribers even when
        shutdown destroys the publisher right after (a reliable writer deleted with data in flight drops it)."""
        try:
            self.release_node()
        finally:
            made = self._entities() - self._own
            deadline = time.monotonic() + RELEASE_ACK_S
            for pub in [e for e in made if e in set(self.publishers)]:
                try:
                    pub.wait_for_all_acked(Duration(seconds=max(0.0, deadline - time.monotonic())))
                except Exception as err:  # (a context already shut down: nothing to wait for)
                    self.get_logger().debug(f'not waiting for acknowledgements: {err}')
            for entity in made:
                if isinstance(entity, LifecyclePublisher):
                    self.destroy_lifecycle_publisher(entity)
                elif entity in set(self.publishers):
                    self.destroy_publisher(entity)
                elif entity in set(self.subscriptions):
                    self.destroy_subscription(entity)
                elif entity in set(self.timers):
                    self.destroy_timer(entity)
                elif entity in set(self.clients):
                    self.destroy_client(entity)
                else:
                    self.destroy_service(entity)

    def _report(self, transition: str, err: BaseException) -> None:
        """Log and publish on /diagnostics why ``transition`` failed."""
        first = str(err).strip().splitlines()[0] if str(err).strip() else ''
        reason = first if is_refusal(err) else f'{type(err).__name__}: {first}'
        self.lifecycle_error = f'{transition} failed: {reason}'
        self._last_exception = err
        if not (self._starting and is_refusal(err)):
            self.get_logger().error(self.lifecycle_error)
        self._lifecycle_status = (transition, reason)
        try:
            self._repeat_status()
        except Exception as publish_err:  # (a context already shut down): the log has it
            self.get_logger().error(f'/diagnostics not published: {publish_err}')

    def _repeat_status(self) -> None:
        """Publish the failed transition's status (ERROR, its reason, the state now), if one failed last."""
        if self._lifecycle_status is None or self.lifecycle_error is None:
            return
        transition, reason = self._lifecycle_status
        self._lifecycle_diag.publish(diagnostic_array(self, [status(
            f'gimbal_friction/{self.get_name()}/lifecycle', ERROR, self.lifecycle_error, self.get_name(),
            {'transition': transition, 'reason': reason})]))

    def _run(self, transition: str, body: Callable[[], None], then: str, refusal: Any = FAILURE) -> Any:
        """Run a transition's ``body``: SUCCESS (state ``then``), or ``refusal`` for a refusal and ERROR for an
        unexpected exception, with the reason reported."""
        try:
            body()
        except Exception as err:
            self._report(transition, err)
            return refusal if is_refusal(err) else ERROR_RETURN
        self.lifecycle_state = then
        self.lifecycle_error = None
        self._lifecycle_status = None
        self._last_exception = None
        return SUCCESS

    # ------------------------------------------------------------------ transitions
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        def body() -> None:
            try:
                self.configure_node()
            except BaseException:
                self._release()   # nothing half-made stays: the node stays unconfigured
                raise
        return self._run('configure', body, INACTIVE)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        def body() -> None:
            if super(ManagedNode, self).on_activate(state) != SUCCESS:   # the LifecyclePublishers publish
                raise RuntimeError('a managed entity refused to activate')
            self.lifecycle_state = ACTIVE
            self.start_output()
        return self._run('activate', body, ACTIVE)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._run('deactivate', self._deactivate, INACTIVE)

    def _deactivate(self) -> None:
        try:
            self.stop_output()
        finally:
            super().on_deactivate(LifecycleState(state_id=3, label=ACTIVE))   # the LifecyclePublishers stop
            self.lifecycle_state = INACTIVE

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        def body() -> None:
            self.lifecycle_state = UNCONFIGURED
            self._release()
        return self._run('cleanup', body, UNCONFIGURED)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._run('shutdown', self._shutdown, FINALIZED, refusal=ERROR_RETURN)

    def _shutdown(self) -> None:
        try:
            if self.active:
                self._deactivate()
        finally:
            if self.configured:
                self.lifecycle_state = UNCONFIGURED
                self._release()
            self.lifecycle_state = FINALIZED

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Error processing: everything released, the reason (reported by the failed transition) kept; back to
        unconfigured."""
        try:
            if self.active:
                self._deactivate()
        except Exception as err:
            self.get_logger().error(f'error processing: deactivating failed: {err}')
        try:
            self._release()
        except Exception as err:
            self.get_logger().error(f'error processing: releasing failed: {err}')
        self.lifecycle_state = UNCONFIGURED
        return SUCCESS

    def close(self) -> None:
        """At the end of the process (``run_node``, the in-process harness): shut down (the deactivation's work
        done if active). Done here directly where the state machine cannot run any more (ROS already shut
        down)."""
        if self.lifecycle_state == FINALIZED:
            return
        try:
            self.trigger_shutdown()
        except Exception as err:  # (rclpy's RCLError: the state machine is gone)
            self.get_logger().warning(f'shutdown transition not available ({err}): shutting down directly')
        if self.lifecycle_state != FINALIZED:
            self._shutdown()
