"""The executor every node spins on (pose4d_ros/nodes/common.py): rclpy's events executor, or
its SingleThreadedExecutor when POSE4D_EXECUTOR=single; anything else is refused by name."""

from __future__ import annotations

import os
import signal
import subprocess

import pytest
from harness import executable

from pose4d_ros.nodes.common import EXECUTOR_ENV, executor
from pose4d_ros.nodes.params import ParameterError


def test_the_executor_follows_the_environment(ros, monkeypatch):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    node = rclpy.create_node('pose4d_executor_probe', context=ros.context)
    try:
        monkeypatch.delenv(EXECUTOR_ENV, raising=False)
        ex = executor(node)
        assert type(ex).__name__ == 'EventsExecutor'
        ex.shutdown()
        monkeypatch.setenv(EXECUTOR_ENV, 'single')
        ex = executor(node)
        assert isinstance(ex, SingleThreadedExecutor)
        ex.shutdown()
        monkeypatch.setenv(EXECUTOR_ENV, 'multi')
        with pytest.raises(ParameterError, match="POSE4D_EXECUTOR='multi': use events or single"):
            executor(node)
    finally:
        node.destroy_node()


@pytest.mark.parametrize('choice, code', [('single', 0), ('threads', 2)])
def test_a_node_serves_on_the_chosen_executor_or_says_why_not(choice, code):
    env = {**os.environ, EXECUTOR_ENV: choice}
    proc = subprocess.Popen([str(executable('tracker'))], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=8)  # a refused setting ends the node at once
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)  # a serving node stops on Ctrl-C
        out, _ = proc.communicate(timeout=20)
    assert proc.returncode == code, out
    assert ('POSE4D_EXECUTOR' in out) == (code != 0), out
    assert 'tracking /pose4d/parts' in out or code != 0, out


def test_diagnostics_due_as_the_context_shuts_down_are_dropped_quietly():
    # Ctrl-C shuts the context down while the diagnostics timer may fire once more: that last
    # publish has no clock or publisher left, and must not end the node with a FATAL traceback
    import rclpy

    from pose4d_ros.nodes.common import StageMonitor

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('pose4d_monitor_probe', context=context)
    try:
        monitor = StageMonitor(node, 'probe')
        monitor.publish()
        context.shutdown()
        monitor.publish()
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
