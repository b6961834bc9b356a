"""The FR3 description against the model libfranka receives from franky-sim (`load_model()`): the
hand frame's pose, the end-effector Jacobian, gravity torque and mass matrix agree to 1e-6.

libfranka's EE frame is the flange with F_T_EE (the Franka Hand's default: 0.1034 m along z,
-45° about z), and its dynamics include the end-effector load of the state (m_total, F_x_Ctotal,
I_total: the hand's default 0.73 kg); phri's URDF models the same hand as a rigid link and the
same TCP frame, so the frames and loads coincide. The state's gravity vector (O_ddP_O) is zero in
franky-sim's state, so the test sets it to (0, 0, -9.81) m/s² before asking for gravity.
"""

from __future__ import annotations

import numpy as np
import pylibfranka
import pytest

import phri
import phri.config
import phri.exceptions
import phri.robots
from phri.franka.sim_server import SimServer

CONFIGS = [
    [0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785],
    [0.3, -0.5, 0.2, -2.0, 0.4, 1.8, -0.6],
    [-1.2, 0.8, -0.7, -1.1, -1.5, 2.9, 1.9],
    [2.0, 1.2, 1.5, -0.4, 2.1, 0.8, -2.5],
]
TOL = 1e-6


@pytest.fixture(scope="module")
def libfranka():
    with SimServer("127.0.14.9") as server:
        robot = pylibfranka.Robot(server.host, pylibfranka.RealtimeConfig.kIgnore)
        state = robot.read_once()
        yield state, robot.load_model()
        del robot


def test_fr3_matches_libfranka_model(libfranka):
    state, model = libfranka
    fr3 = phri.Robot.fr3()
    tcp = fr3.hand_frame
    # The pose the server reports for its own state (O_T_EE, column-major, single precision).
    q0 = np.array(state.q)
    o_t_ee = np.array(state.O_T_EE).reshape(4, 4, order="F")
    np.testing.assert_allclose(fr3.frame_pose(tcp, q0), o_t_ee, atol=1e-6)
    state.O_ddP_O = [0.0, 0.0, -9.81]
    for q in CONFIGS:
        q = np.array(q)
        fr3.check_limits(q)
        state.q = list(q)
        g = np.array(model.gravity(state))
        m = np.array(model.mass(state)).reshape(7, 7, order="F")
        j = np.array(model.zero_jacobian(state)).reshape(6, 7, order="F")
        assert np.abs(g).max() > 1.0
        np.testing.assert_allclose(fr3.gravity(q), g, atol=TOL, rtol=0)
        np.testing.assert_allclose(fr3.mass_matrix(q), m, atol=TOL, rtol=0)
        np.testing.assert_allclose(fr3.jacobian(tcp, q), j, atol=TOL, rtol=0)


def test_descriptions_carry_their_interaction_thresholds():
    assert phri.robots.load("jaco2").thresholds == (8.0, 8.0, 8.0, 2.0, 1.0, 1.0, 1.0)
    fr3 = phri.robots.load("fr3").thresholds
    assert fr3 is not None and len(fr3) == 7 and all(t > 0 for t in fr3)


def test_fr3_collision_model_is_complete():
    fr3 = phri.Robot.fr3()
    assert fr3.collision_complete, fr3.collision_incomplete_reason


def test_a_task_for_another_robot_is_a_config_error():
    task = phri.config.load_task("table")
    assert task.robot == "jaco2"
    with pytest.raises(phri.exceptions.ConfigError, match="posed for robot 'jaco2'"):
        task.feature_set(phri.Robot.fr3())


@pytest.mark.parametrize("name", ["fr3_coffee", "fr3_human", "fr3_laptop", "fr3_table"])
def test_fr3_tasks_plan_clear_and_converged(name):
    from phri._phri import TrajectoryOptimizer

    task = phri.config.load_task(name)
    fr3 = phri.Robot.fr3()
    assert task.robot == "fr3"
    fr3.check_limits(task.start)
    fr3.check_limits(task.goal)
    features = task.feature_set(fr3)
    optimizer = TrajectoryOptimizer(features, task.waypoints, duration=task.duration, speed_fraction=0.5)
    _, info = optimizer.solve(task.vector("true"), task.start, task.goal)
    assert info.feasible and info.converged
    assert info.max_violation <= TrajectoryOptimizer.CLEARANCE_TOLERANCE


def test_the_study_figures_read_an_fr3_log_with_the_fr3(tmp_path):
    """The path figure's forward kinematics are those of the task's robot, not the JACO2's."""
    from phri.study import figures

    robot = phri.Robot.fr3()
    q = np.array(CONFIGS)
    log = tmp_path / "fr3.npz"
    np.savez(log, t=np.linspace(0.0, 3.0, len(q)), q=q, desired=q)
    paths = figures.read_paths(log, None, "fr3")
    np.testing.assert_allclose(
        paths["executed"], robot.frame_pose(robot.feature_frame, q)[:, :3, 3], atol=1e-12
    )
