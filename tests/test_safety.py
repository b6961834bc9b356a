"""Whole-arm safety in simulation: the study's episodes keep every body of the arm and the cup clear
of the furniture (phri's sphere model and PyBullet's own collision geometry both say so), and the
run-time virtual wall holds the arm off the table while a person pushes it down."""

from __future__ import annotations

import numpy as np
import pytest

import phri
from phri.sim import EpisodeConfig, ParticipantParams, Planner, World
from phri.sim.episode import simulate_episode
from phri.sim.world import HAND

TASKS = ("human", "coffee", "table", "laptop")
#: The run-time wall's margin [m] (ImpedanceController's default), and the tolerance of the checks.
WALL_MARGIN = 0.005
TOLERANCE = 1e-3


def furniture_distances(robot: phri.Robot, task: phri.Task, q: np.ndarray) -> np.ndarray:
    """Each moving body's smallest distance to the task's furniture at each row of `q` [m] (the base
    and link 1 stand on the mount and are left out, as the planner leaves them out)."""
    names = [o.name for o in task.scene.objects if o.kind == "furniture"]
    columns = [task.scene.names.index(n) for n in names]
    bodies = [k for k, b in enumerate(robot.collision_bodies) if not b.endswith(("link_base", "link_1"))]
    return robot.scene_distances(q, task.scene)[:, bodies][:, :, columns]


def pybullet_contacts(world: World, task: phri.Task, q: np.ndarray) -> list[tuple[float, str, str]]:
    """(row time index, arm link, object) of every contact of the arm or the cup with the task's
    furniture in PyBullet's own collision geometry (the URDF's cylinders and boxes), replaying `q`."""
    p, c = world.p, world.client
    world.set_scene(task.scene)
    names = {j: n for n, j in world.links.items()}
    contacts = []
    for row, qk in enumerate(q):
        world.reset(qk)
        p.performCollisionDetection(physicsClientId=c)
        for obj in task.scene.objects:
            if obj.kind != "furniture":
                continue
            for hit in p.getClosestPoints(world.robot_id, world.bodies[obj.name], 0.0, physicsClientId=c):
                contacts.append((row, names.get(hit[3], str(hit[3])), obj.name))
    return contacts


@pytest.mark.slow
@pytest.mark.parametrize("name", TASKS)
def test_study_episodes_keep_the_arm_off_the_furniture(world, name) -> None:
    task = phri.load_task(name)
    planner = Planner(task, world)
    for strategy in ("impedance", "learning"):
        result, error = simulate_episode(
            task, world, ParticipantParams(), EpisodeConfig(strategy=strategy), seed=3, planner=planner
        )
        assert error is None
        q = result.log_arrays["q"]
        d = furniture_distances(world.model, task, q)
        assert d.min() >= WALL_MARGIN - TOLERANCE, f"{name}/{strategy}: a body {d.min():.4f} m from furniture"
        assert result.min_clearance <= d.min() + 1e-12
        assert result.log_arrays["distances"].shape == (
            len(q),
            len(world.model.collision_bodies),
            len(task.scene),
        )
        assert pybullet_contacts(world, task, q[::5]) == [], f"{name}/{strategy}: PyBullet sees contact"


@pytest.mark.slow
def test_the_wall_holds_the_cup_off_the_table_under_a_hard_push(world) -> None:
    """A 40 N push straight down at the hand for 6 s on the table task's desired path (the study's
    participants push with 25–35 N): with the
    wall, no body comes closer to the table than its margin (minus 1 mm); without it, the cup is
    driven into the table (so the check can fail)."""
    task = phri.load_task("table")
    planner = Planner(task, world)
    reference = phri.TimedTrajectory(planner.desired, task.duration)
    model = world.model
    dt = world.params.timestep

    def lowest(wall: bool) -> tuple[float, float]:
        controller = phri.ImpedanceController(model, scene=task.scene, wall=wall)
        world.set_scene(task.scene)
        world.reset(task.start)
        closest, force = np.inf, 0.0
        tau = np.empty(7)
        for k in range(int(9.0 / dt)):
            t = k * dt
            q, qd = world.state()
            q_ref, qd_ref, _ = reference.sample(t)
            controller.torque_implicit(q, qd, q_ref, qd_ref, dt, out=tau)
            force = max(force, controller.wall_force)
            push = np.array([0.0, 0.0, -40.0]) if 3.0 <= t < 9.0 else None
            world.step(tau, push, None)
            if k % 10 == 0:
                closest = min(closest, float(furniture_distances(model, task, q[None])[0].min()))
        return closest, force

    guarded, force = lowest(wall=True)
    assert force > 0.0, "the wall never acted"
    assert guarded >= WALL_MARGIN - TOLERANCE, f"with the wall a body came {guarded:.4f} m from the table"
    unguarded, _ = lowest(wall=False)
    assert unguarded < WALL_MARGIN - TOLERANCE, f"without the wall the push only got to {unguarded:.4f} m"
    assert HAND in world.links
