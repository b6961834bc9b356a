"""phri.Robot: contracts (shapes, dtypes, batching, exceptions) and agreement with PyBullet, for the
JACO2 and for robots written here (prismatic joints, tilted non-unit axes, a sub-chain of a tree).

PyBullet reads the same URDF, so any rounding in the file is shared and the two agree to machine
precision: the contract is 1e-6, and double-precision quantities are held to ATOL = 1e-9
(observed: ~1e-14). The exception is getLinkState's worldLinkFrame fields (4, 5): pybullet composes them
client-side in single precision (every value returned is an exact float32, asserted below), so the
position is off by up to ~1e-7 m and the rotation entries by up to ~10 float32 ulps (1.2e-6 observed
over 2000 configurations). Those fields get a float32-sized tolerance; the exact check of every link
frame composes the double-precision COM frame (fields 0, 1) with the local inertial frame (2, 3).
"""

from __future__ import annotations

import importlib.resources
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pybullet as p
import pytest
from conftest import PyBulletRobot, jaco2_urdf_path, random_configurations

import phri
from phri import exceptions as ex

ATOL = 1e-9  # double precision vs double precision, same URDF
F32_POSITION_ATOL = 1e-6  # pybullet's single-precision worldLinkFrame position [m]
F32_ROTATION_ATOL = 16 * float(np.finfo(np.float32).eps)  # its single-precision rotation entries
N_CONFIGS = 200

PREFIX = "j2s7s300_"
LINK_7 = PREFIX + "link_7"
END_EFFECTOR = PREFIX + "end_effector"
CUP_FRAME = PREFIX + "cup_frame"
JACOBIAN_FRAMES = [LINK_7, END_EFFECTOR, CUP_FRAME]


# --------------------------------------------------------------------------------------------------
# helpers


def quat_to_matrix(quat: tuple[float, float, float, float]) -> np.ndarray:
    """Rotation matrix of a pybullet quaternion (x, y, z, w), in double precision."""
    x, y, z, w = quat
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def set_q(pb: PyBulletRobot, q: np.ndarray) -> None:
    for joint, value in zip(pb.joints, q, strict=True):
        p.resetJointState(pb.body, joint, float(value), physicsClientId=pb.client)


def link_frames(pb: PyBulletRobot, link: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(position, rotation) of a link's URDF frame composed in double precision from the COM frame
    and the local inertial frame, then pybullet's own single-precision worldLinkFrame (fields 4, 5)."""
    st = p.getLinkState(pb.body, link, computeForwardKinematics=True, physicsClientId=pb.client)
    r_com, p_com = quat_to_matrix(st[1]), np.array(st[0])
    r_in, p_in = quat_to_matrix(st[3]), np.array(st[2])
    r_link = r_com @ r_in.T
    p_link = p_com - r_link @ p_in
    return p_link, r_link, np.array(st[4]), quat_to_matrix(st[5])


def inertial_frame(pb: PyBulletRobot, link: int) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation) of a link's inertial (COM) frame in its URDF link frame."""
    info = p.getDynamicsInfo(pb.body, link, physicsClientId=pb.client)
    return np.array(info[3]), quat_to_matrix(info[4])


def pybullet_jacobian(pb: PyBulletRobot, link: int, point: np.ndarray, q: np.ndarray) -> np.ndarray:
    """6×n world-aligned Jacobian of `point` (given in the URDF link frame) from calculateJacobian.

    pybullet's localPosition is the point relative to the URDF link origin, expressed in the axes of
    the inertial frame (bullet3 issue #4668; verified below: with the COM *position* subtracted, as the
    quickstart guide's wording suggests, link_7 disagrees by ~0.06 m/s per rad/s)."""
    _, r_in = inertial_frame(pb, link)
    local = r_in.T @ point
    zeros = [0.0] * len(q)
    lin, ang = p.calculateJacobian(
        pb.body, link, local.tolist(), q.tolist(), zeros, zeros, physicsClientId=pb.client
    )
    return np.vstack([np.array(lin), np.array(ang)])


def assert_close(actual: np.ndarray, desired: np.ndarray, atol: float, what: str) -> None:
    err = np.max(np.abs(np.asarray(actual) - np.asarray(desired)))
    assert err <= atol, f"{what}: max |error| = {err:.3e} > {atol:.0e}"


def payload_urdf(mass: float, com: np.ndarray, inertia: np.ndarray) -> str:
    """The shipped URDF with an extra link rigidly attached at cup_frame (identity pose)."""
    c = [float(v) for v in com]
    i = np.asarray(inertia, dtype=float).tolist()
    extra = (
        f'<link name="payload"><inertial><mass value="{float(mass)!r}"/>'
        f'<origin xyz="{c[0]!r} {c[1]!r} {c[2]!r}" rpy="0 0 0"/>'
        f'<inertia ixx="{i[0][0]!r}" ixy="{i[0][1]!r}" ixz="{i[0][2]!r}" '
        f'iyy="{i[1][1]!r}" iyz="{i[1][2]!r}" izz="{i[2][2]!r}"/></inertial></link>'
        f'<joint name="joint_payload" type="fixed"><parent link="{CUP_FRAME}"/>'
        '<child link="payload"/><origin xyz="0 0 0" rpy="0 0 0"/></joint>'
    )
    text = jaco2_urdf_path().read_text()
    assert text.count("</robot>") == 1
    return text.replace("</robot>", extra + "\n</robot>")


def deg(values: list[float]) -> np.ndarray:
    return np.radians(np.array(values))


# --------------------------------------------------------------------------------------------------
# the model


def test_model_matches_the_urdf_as_pybullet_reads_it(robot: phri.Robot, pybullet_jaco2: PyBulletRobot):
    client, body, links, joints = pybullet_jaco2
    assert robot.name == "j2s7s300"
    assert robot.nq == 7 == len(joints)
    infos = [p.getJointInfo(body, j, physicsClientId=client) for j in joints]
    assert robot.joint_names == [info[1].decode() for info in infos]
    assert sorted(robot.frame_names) == sorted(links)
    for k, info in enumerate(infos):
        lower, upper, effort, velocity = info[8], info[9], info[10], info[11]
        if lower > upper:  # pybullet's encoding of a continuous joint
            assert robot.lower_limits[k] == -np.inf and robot.upper_limits[k] == np.inf
        else:
            assert robot.lower_limits[k] == lower and robot.upper_limits[k] == upper
        assert robot.effort_limits[k] == effort
        assert robot.velocity_limits[k] == velocity


FK_VECTORS = [  # forward kinematics of the j2s7s300 description (kinova-ros) at reference poses
    ("candle", np.full(7, np.pi), END_EFFECTOR, (0.0, -0.0130, 1.2603)),
    ("candle", np.full(7, np.pi), LINK_7, (0.0, -0.0130, 1.1003)),
    (
        "home",
        deg([103.366, 197.13, 180.070, 43.4309, 265.11, 257.271, 287.9276]),
        END_EFFECTOR,
        (0.21275, -0.26827, 0.50506),
    ),
    (
        "place_lower",
        deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]),
        LINK_7,
        (-0.5822, 0.3302, 0.1059),
    ),
]


@pytest.mark.parametrize(
    ("pose", "q", "frame", "position"), FK_VECTORS, ids=[f"{v[0]}-{v[2]}" for v in FK_VECTORS]
)
def test_forward_kinematics_test_vectors(robot: phri.Robot, pose, q, frame, position):
    t = robot.frame_pose(frame, q)
    assert_close(t[:3, 3], position, 1e-4, f"{frame} position at {pose}")


def test_candle_end_effector_orientation(robot: phri.Robot):
    t = robot.frame_pose(END_EFFECTOR, np.full(7, np.pi))
    assert_close(t[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], 1e-4, "end_effector rotation at candle")


def test_frame_poses_are_rigid_transforms(robot: phri.Robot, draw_q):
    for q in draw_q(20):
        for frame in robot.frame_names:
            t = robot.frame_pose(frame, q)
            assert_close(t[3], [0, 0, 0, 1], 0.0, f"{frame} last row")
            assert_close(t[:3, :3] @ t[:3, :3].T, np.eye(3), 1e-12, f"{frame} orthonormality")
            assert np.linalg.det(t[:3, :3]) == pytest.approx(1.0, abs=1e-12)
    assert_close(robot.frame_pose("root", draw_q(1)[0]), np.eye(4), 0.0, "root (the base) pose")


# --------------------------------------------------------------------------------------------------
# agreement with PyBullet over random configurations


def test_link_frames_match_pybullet(robot: phri.Robot, pybullet_jaco2: PyBulletRobot, draw_q):
    movable_links = {name: i for name, i in pybullet_jaco2.links.items() if i >= 0}
    assert len(movable_links) == len(robot.frame_names) - 1  # every frame but the base link
    worst_double = worst_position = worst_rotation = 0.0
    for q in draw_q(N_CONFIGS):
        set_q(pybullet_jaco2, q)
        for name, link in movable_links.items():
            t = robot.frame_pose(name, q)
            p_link, r_link, p_f32, r_f32 = link_frames(pybullet_jaco2, link)
            err_double = max(np.abs(t[:3, 3] - p_link).max(), np.abs(t[:3, :3] - r_link).max())
            assert err_double <= ATOL, f"{name} at q={q.tolist()}: {err_double:.3e}"
            err_position = np.abs(t[:3, 3] - p_f32).max()
            err_rotation = np.abs(t[:3, :3] - r_f32).max()
            assert err_position <= F32_POSITION_ATOL, f"{name} worldLinkFramePosition at q={q.tolist()}"
            assert err_rotation <= F32_ROTATION_ATOL, f"{name} worldLinkFrameOrientation at q={q.tolist()}"
            worst_double = max(worst_double, err_double)
            worst_position, worst_rotation = (
                max(worst_position, err_position),
                max(worst_rotation, err_rotation),
            )
    print(
        f"link frames: worst {worst_double:.1e} (double); worldLinkFrame (float32): "
        f"position {worst_position:.1e} m, rotation {worst_rotation:.1e}"
    )


def test_pybullet_world_link_frame_is_single_precision(pybullet_jaco2: PyBulletRobot, draw_q):
    """Why fields 4 and 5 get a float32 tolerance: pybullet returns them as float32 numbers."""
    set_q(pybullet_jaco2, draw_q(1)[0])
    client, body, links, _ = pybullet_jaco2
    st = p.getLinkState(body, links[LINK_7], computeForwardKinematics=True, physicsClientId=client)
    assert all(float(np.float32(v)) == v for v in st[4] + st[5])
    assert not all(float(np.float32(v)) == v for v in st[0] + st[1])  # the COM frame is double


@pytest.mark.parametrize("frame", JACOBIAN_FRAMES)
def test_jacobians_match_pybullet(robot: phri.Robot, pybullet_jaco2: PyBulletRobot, draw_q, frame: str):
    link = pybullet_jaco2.links[frame]
    com, _ = inertial_frame(pybullet_jaco2, link)
    worst = 0.0
    for q in draw_q(N_CONFIGS):
        jac = robot.jacobian(frame, q)
        expected = pybullet_jacobian(pybullet_jaco2, link, np.zeros(3), q)
        err = np.abs(jac - expected).max()
        assert err <= ATOL, f"{frame} Jacobian at q={q.tolist()}: {err:.3e}"
        worst = max(worst, err)
        # The same Jacobian moved to the link's COM (v_c = v_o + ω × (c − o)) pins down pybullet's
        # localPosition convention, so the comparison above cannot pass by a shared misreading.
        t = robot.frame_pose(frame, q)
        r = t[:3, :3] @ com
        shifted = jac.copy()
        shifted[:3] -= np.cross(r, jac[3:], axisa=0, axisb=0, axisc=0)
        expected_com = pybullet_jacobian(pybullet_jaco2, link, com, q)
        assert_close(shifted, expected_com, ATOL, f"{frame} COM Jacobian at q={q.tolist()}")
    print(f"{frame} Jacobian: worst {worst:.1e}")


def test_inverse_dynamics_matches_pybullet(robot: phri.Robot, pybullet_jaco2: PyBulletRobot, draw_q, rng):
    client, body, _, _ = pybullet_jaco2
    qs = draw_q(N_CONFIGS)
    vmax = robot.velocity_limits
    qds = rng.uniform(-3 * vmax, 3 * vmax, qs.shape)
    qdds = rng.uniform(-10.0, 10.0, qs.shape)
    worst = 0.0
    for q, qd, qdd in zip(qs, qds, qdds, strict=True):
        expected = p.calculateInverseDynamics(
            body, q.tolist(), qd.tolist(), qdd.tolist(), physicsClientId=client
        )
        tau = robot.inverse_dynamics(q, qd, qdd)
        err = np.abs(tau - expected).max()
        assert err <= ATOL, f"tau at q={q.tolist()}, qd={qd.tolist()}, qdd={qdd.tolist()}: {err:.3e}"
        worst = max(worst, err)
        zero = [0.0] * 7
        nle = p.calculateInverseDynamics(body, q.tolist(), qd.tolist(), zero, physicsClientId=client)
        assert_close(
            robot.nonlinear_effects(q, qd), nle, ATOL, f"C q̇ + g at q={q.tolist()}, qd={qd.tolist()}"
        )
        grav = p.calculateInverseDynamics(body, q.tolist(), zero, zero, physicsClientId=client)
        assert_close(robot.gravity(q), grav, ATOL, f"g at q={q.tolist()}")
    print(f"inverse dynamics: worst {worst:.1e} N·m")


def test_mass_matrix_matches_pybullet(robot: phri.Robot, pybullet_jaco2: PyBulletRobot, draw_q):
    client, body, _, _ = pybullet_jaco2
    worst = 0.0
    for q in draw_q(N_CONFIGS):
        expected = np.array(p.calculateMassMatrix(body, q.tolist(), physicsClientId=client))
        m = robot.mass_matrix(q)
        err = np.abs(m - expected).max()
        assert err <= ATOL, f"M at q={q.tolist()}: {err:.3e}"
        worst = max(worst, err)
        np.testing.assert_array_equal(m, m.T)
        assert np.linalg.eigvalsh(m).min() > 0.0, f"M not positive definite at q={q.tolist()}"
    print(f"mass matrix: worst {worst:.1e} kg·m²")


def test_dynamics_are_consistent(robot: phri.Robot, draw_q, rng):
    """τ = M(q) q̈ + C(q, q̇) q̇ + g(q), and gravity() is the zero-velocity case of nonlinear_effects()."""
    qs = draw_q(50)
    qds = rng.uniform(-2, 2, qs.shape)
    qdds = rng.uniform(-5, 5, qs.shape)
    m = robot.mass_matrix(qs)
    expected = np.einsum("nij,nj->ni", m, qdds) + robot.nonlinear_effects(qs, qds)
    assert_close(robot.inverse_dynamics(qs, qds, qdds), expected, ATOL, "τ vs M q̈ + h")
    assert_close(robot.nonlinear_effects(qs, np.zeros_like(qs)), robot.gravity(qs), ATOL, "h(q, 0) vs g(q)")


def test_forward_dynamics_solves_the_equation_of_motion(robot: phri.Robot, draw_q, rng):
    """q̈ = M⁻¹(τ − h), checked against numpy's solve of phri's own M and h (single and batched)."""
    qs = draw_q(50)
    qds = rng.uniform(-2, 2, qs.shape)
    taus = rng.uniform(-20, 20, qs.shape)
    expected = np.linalg.solve(robot.mass_matrix(qs), (taus - robot.nonlinear_effects(qs, qds))[..., None])[
        ..., 0
    ]
    assert_close(robot.forward_dynamics(qs, qds, taus), expected, 1e-8, "q̈ vs solve(M, τ − h)")
    assert_close(robot.forward_dynamics(qs[3], qds[3], taus[3]), expected[3], 1e-8, "one row")
    with pytest.raises(ex.NonFiniteError, match="tau"):
        robot.forward_dynamics(qs[0], qds[0], np.full(7, np.nan))


def test_forward_dynamics_steps_as_pybullet_does():
    """The study's PyBullet world (the JACO2 with its cup, no scene, no joint damping) integrates
    forward dynamics by semi-implicit Euler: q̇ += dt·q̈, then q += dt·q̇. Given the same torques, that
    step with phri's forward dynamics follows PyBullet's joint trajectory to rounding for 1 s."""
    from phri.sim import World

    with World() as world:
        model, dt = world.model, world.params.timestep
        q = np.array(phri.load_task("coffee").start, dtype=float)
        world.reset(q)
        qd = np.zeros(7)
        worst = 0.0
        for k in range(1000):
            q_pb, qd_pb = world.state()
            worst = max(worst, float(np.abs(q_pb - q).max()))
            # A torque that moves every joint (gravity, a sweep, damping on PyBullet's state).
            tau = model.gravity(q_pb) + 3.0 * np.sin(np.arange(7) + 3.0 * k * dt) - 2.0 * qd_pb
            world.step(tau)
            qd = qd + dt * model.forward_dynamics(q, qd, tau)
            q = q + dt * qd
        moved = float(np.abs(world.state()[0] - phri.load_task("coffee").start).max())
    assert moved > 0.1, f"the arm moved only {moved:.3f} rad: the comparison says nothing"
    assert worst < 1e-9, f"phri's step left PyBullet's joint trajectory by {worst:.2e} rad"


# --------------------------------------------------------------------------------------------------
# payload


def test_point_payload_changes_gravity_as_in_pybullet(
    robot: phri.Robot, load_pybullet, draw_q, tmp_path: Path
):
    """0.3 kg at cup_frame: phri's with_payload vs PyBullet loading the URDF with a 0.3 kg link there."""
    path = tmp_path / "jaco2_cup.urdf"
    path.write_text(payload_urdf(0.3, np.zeros(3), np.zeros((3, 3))))
    pb = load_pybullet(path)
    plain = load_pybullet(jaco2_urdf_path())
    loaded = robot.with_payload(CUP_FRAME, 0.3)
    zero = [0.0] * 7
    largest_change = 0.0
    for q in draw_q(N_CONFIGS):
        g_pb = np.array(
            p.calculateInverseDynamics(pb.body, q.tolist(), zero, zero, physicsClientId=pb.client)
        )
        g0_pb = np.array(
            p.calculateInverseDynamics(plain.body, q.tolist(), zero, zero, physicsClientId=plain.client)
        )
        g, g0 = loaded.gravity(q), robot.gravity(q)
        assert_close(g, g_pb, ATOL, f"loaded gravity at q={q.tolist()}")
        assert_close(g - g0, g_pb - g0_pb, ATOL, f"gravity change at q={q.tolist()}")
        largest_change = max(largest_change, np.abs(g - g0).max())
    # 0.3 kg at up to ~0.9 m from the shoulder: the change is a few N·m, far above the tolerance.
    assert largest_change > 1.0


def test_general_payload_matches_pybullet_and_an_equivalent_urdf(
    robot: phri.Robot, load_pybullet, draw_q, rng, tmp_path: Path
):
    """An offset payload with a full inertia tensor (products of inertia included) in cup_frame axes."""
    mass, com = 0.3, np.array([0.012, -0.02, 0.045])
    # A solid 4 × 6 × 9 cm box turned about an oblique axis, so that every product of inertia is nonzero
    # (a physical tensor: pybullet zeroes one whose principal moments break the triangle inequality).
    x, y, z = 0.04, 0.06, 0.09
    box = mass / 12 * np.diag([y * y + z * z, x * x + z * z, x * x + y * y])
    k = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rot = np.eye(3) + np.sin(0.9) * kx + (1 - np.cos(0.9)) * kx @ kx  # Rodrigues, 0.9 rad about k
    inertia = rot @ box @ rot.T  # [kg·m²] about the payload's COM, cup_frame axes
    assert np.abs(inertia[np.triu_indices(3, 1)]).min() > 5e-6
    path = tmp_path / "jaco2_payload.urdf"
    path.write_text(payload_urdf(mass, com, inertia))
    pb = load_pybullet(path)
    loaded = robot.with_payload(CUP_FRAME, mass, com=com, inertia=inertia)
    from_file = phri.Robot.from_urdf(path, base="root", tip=END_EFFECTOR)
    qs = draw_q(N_CONFIGS)
    qds = rng.uniform(-2, 2, qs.shape)
    qdds = rng.uniform(-5, 5, qs.shape)
    for q, qd, qdd in zip(qs, qds, qdds, strict=True):
        where = f"q={q.tolist()}, qd={qd.tolist()}, qdd={qdd.tolist()}"
        tau_pb = p.calculateInverseDynamics(
            pb.body, q.tolist(), qd.tolist(), qdd.tolist(), physicsClientId=pb.client
        )
        m_pb = np.array(p.calculateMassMatrix(pb.body, q.tolist(), physicsClientId=pb.client))
        assert_close(loaded.inverse_dynamics(q, qd, qdd), tau_pb, ATOL, f"payload τ at {where}")
        assert_close(loaded.mass_matrix(q), m_pb, ATOL, f"payload M at {where}")
    np.testing.assert_allclose(
        loaded.inverse_dynamics(qs, qds, qdds), from_file.inverse_dynamics(qs, qds, qdds), 0, ATOL
    )
    np.testing.assert_allclose(loaded.mass_matrix(qs), from_file.mass_matrix(qs), 0, ATOL)


def test_with_payload_returns_a_new_robot(robot: phri.Robot, draw_q):
    qs = draw_q(5)
    before = robot.gravity(qs)
    loaded = robot.with_payload(CUP_FRAME, 0.3)
    assert isinstance(loaded, phri.Robot)
    np.testing.assert_array_equal(robot.gravity(qs), before)
    assert not np.array_equal(loaded.gravity(qs), before)
    np.testing.assert_array_equal(robot.with_payload(CUP_FRAME, 0.0).gravity(qs), before)


# --------------------------------------------------------------------------------------------------
# robots other than the JACO2: prismatic joints, tilted and non-unit axes, sub-chains of a tree


#: Axes of the mixed chain's joints (revolute, prismatic, revolute, prismatic): the revolute ones
#: tilted and not unit vectors (norms 0.99998 and 2.5); the prismatic ones tilted unit vectors.
MIXED_AXES = ("0.3 0.4 0.866", "0.48 -0.6 0.64", "1.2 -0.9 2.0", "0.36 0.48 -0.8")

#: A 4-joint chain base → l1 → l2 → l3 → l4 (revolute, prismatic, revolute, prismatic) and a tool fixed
#: to l4: every joint origin and inertial frame rotated by a general rpy, every inertia with products.
MIXED_CHAIN = """<robot name="mixed">
<link name="base"><inertial><mass value="2.0"/><origin xyz="0.01 0 0.05" rpy="0 0 0"/>
  <inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.021" iyz="0.0005" izz="0.018"/></inertial></link>
<link name="l1"><inertial><mass value="1.3"/><origin xyz="0.02 -0.01 0.12" rpy="0.1 -0.2 0.3"/>
  <inertia ixx="0.031" ixy="0.0021" ixz="-0.0013" iyy="0.027" iyz="0.0017" izz="0.012"/></inertial></link>
<link name="l2"><inertial><mass value="0.9"/><origin xyz="-0.03 0.05 0.08" rpy="0.4 0.2 -0.6"/>
  <inertia ixx="0.012" ixy="-0.0011" ixz="0.0009" iyy="0.015" iyz="-0.0014" izz="0.009"/></inertial></link>
<link name="l3"><inertial><mass value="0.7"/><origin xyz="0.01 0.02 -0.04" rpy="-0.3 0.5 0.1"/>
  <inertia ixx="0.008" ixy="0.0007" ixz="0.0005" iyy="0.006" iyz="-0.0006" izz="0.005"/></inertial></link>
<link name="l4"><inertial><mass value="0.4"/><origin xyz="0.05 -0.02 0.03" rpy="0.7 -0.1 0.9"/>
  <inertia ixx="0.003" ixy="-0.0004" ixz="0.0003" iyy="0.004" iyz="0.0002" izz="0.0025"/></inertial></link>
<link name="tool"><inertial><mass value="0.2"/><origin xyz="0 0.01 0.02" rpy="0.2 0.3 0"/>
  <inertia ixx="0.0005" ixy="3e-05" ixz="-2e-05" iyy="0.0006" iyz="4e-05" izz="0.0004"/></inertial></link>
<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
  <origin xyz="0.05 -0.02 0.15" rpy="0.2 -0.1 0.4"/><axis xyz="{0}"/>
  <limit lower="-2.5" upper="2.5" effort="50" velocity="2"/></joint>
<joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/>
  <origin xyz="0.1 0.03 0.25" rpy="-0.5 0.3 0.2"/><axis xyz="{1}"/>
  <limit lower="-0.2" upper="0.3" effort="100" velocity="0.5"/></joint>
<joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/>
  <origin xyz="-0.04 0.12 0.2" rpy="1.1 0.4 -0.7"/><axis xyz="{2}"/>
  <limit lower="-1.7" upper="2.1" effort="30" velocity="2.5"/></joint>
<joint name="j4" type="prismatic"><parent link="l3"/><child link="l4"/>
  <origin xyz="0.07 -0.05 0.1" rpy="0.3 -0.8 1.2"/><axis xyz="{3}"/>
  <limit lower="-0.1" upper="0.15" effort="80" velocity="0.4"/></joint>
<joint name="jt" type="fixed"><parent link="l4"/><child link="tool"/>
  <origin xyz="0.02 0.01 0.09" rpy="0.5 0.25 -0.35"/></joint>
</robot>"""


def mixed_chain_urdf(axes: tuple[str, ...] = MIXED_AXES) -> str:
    return MIXED_CHAIN.format(*axes)


#: A tree rooted at `ground`. A turntable joint (about the vertical) carries `mount`, the base of the
#: sub-chain mount → a1 → a2 → a3 (joints t1 revolute, t2 prismatic, t3 continuous); beside it, a
#: branch `other` that is not below mount. Lumped into the chain's bodies: plate (fixed to mount),
#: camera (fixed to a1), s1 and s2 (a side branch off a2 through a revolute and a prismatic joint,
#: locked at 0), finger and pad (below the tip a3, through a revolute joint, locked at 0).
TREE = """<robot name="tree">
<link name="ground"><inertial><mass value="5.0"/><origin xyz="0 0 0.02" rpy="0 0 0"/>
  <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
<link name="other"><inertial><mass value="1.0"/><origin xyz="0.1 0 0" rpy="0.3 0 0"/>
  <inertia ixx="0.01" ixy="0.001" ixz="0" iyy="0.012" iyz="0" izz="0.009"/></inertial></link>
<link name="mount"><inertial><mass value="1.5"/><origin xyz="0 0.02 0.03" rpy="0.1 0.2 0.3"/>
  <inertia ixx="0.012" ixy="0.0008" ixz="-0.0004" iyy="0.011" iyz="0.0006" izz="0.01"/></inertial></link>
<link name="plate"><inertial><mass value="0.3"/><origin xyz="0.01 0 0" rpy="0 0.4 0"/>
  <inertia ixx="0.001" ixy="0.0001" ixz="0" iyy="0.0012" iyz="0" izz="0.0009"/></inertial></link>
<link name="a1"><inertial><mass value="1.1"/><origin xyz="0.01 0.03 0.14" rpy="-0.2 0.1 0.5"/>
  <inertia ixx="0.025" ixy="-0.0018" ixz="0.0011" iyy="0.022" iyz="0.0013" izz="0.01"/></inertial></link>
<link name="camera"><inertial><mass value="0.25"/><origin xyz="0.02 0 0.01" rpy="0.3 -0.2 0.1"/>
  <inertia ixx="0.0004" ixy="5e-05" ixz="-3e-05" iyy="0.0005" iyz="2e-05" izz="0.0003"/></inertial></link>
<link name="a2"><inertial><mass value="0.8"/><origin xyz="-0.02 0.04 0.09" rpy="0.5 -0.3 0.2"/>
  <inertia ixx="0.01" ixy="0.0009" ixz="-0.0007" iyy="0.012" iyz="0.0011" izz="0.007"/></inertial></link>
<link name="s1"><inertial><mass value="0.35"/><origin xyz="0.04 0 0.02" rpy="0.2 0.2 0.2"/>
  <inertia ixx="0.0015" ixy="-0.0002" ixz="0.0001" iyy="0.0018" iyz="0.0001" izz="0.0012"/></inertial></link>
<link name="s2"><inertial><mass value="0.15"/><origin xyz="0 0.02 0" rpy="-0.4 0 0.3"/>
  <inertia ixx="0.0003" ixy="2e-05" ixz="1e-05" iyy="0.0004" iyz="-3e-05" izz="0.0002"/></inertial></link>
<link name="a3"><inertial><mass value="0.6"/><origin xyz="0.02 -0.01 0.05" rpy="0.1 0.6 -0.4"/>
  <inertia ixx="0.006" ixy="-0.0005" ixz="0.0004" iyy="0.005" iyz="0.0003" izz="0.004"/></inertial></link>
<link name="finger"><inertial><mass value="0.1"/><origin xyz="0.01 0 0.02" rpy="0 0 0.5"/>
  <inertia ixx="0.0002" ixy="1e-05" ixz="0" iyy="0.00025" iyz="2e-05" izz="0.00015"/></inertial></link>
<link name="pad"><inertial><mass value="0.05"/><origin xyz="0 0 0.005" rpy="0.3 0 0"/>
  <inertia ixx="3e-05" ixy="2e-06" ixz="0" iyy="4e-05" iyz="0" izz="2e-05"/></inertial></link>
<joint name="turntable" type="revolute"><parent link="ground"/><child link="mount"/>
  <origin xyz="0.3 -0.2 0.1" rpy="0 0 0.7"/><axis xyz="0 0 1"/>
  <limit lower="-3" upper="3" effort="40" velocity="1.5"/></joint>
<joint name="j_other" type="revolute"><parent link="ground"/><child link="other"/>
  <origin xyz="-0.4 0.1 0.2" rpy="0.3 0.2 0.1"/><axis xyz="0 1 0"/>
  <limit lower="-1" upper="1" effort="40" velocity="1.5"/></joint>
<joint name="j_plate" type="fixed"><parent link="mount"/><child link="plate"/>
  <origin xyz="0 0.05 0.02" rpy="0.2 0 0.3"/></joint>
<joint name="t1" type="revolute"><parent link="mount"/><child link="a1"/>
  <origin xyz="0.02 0.03 0.12" rpy="0.1 -0.3 0.2"/><axis xyz="0.3 0.4 0.866"/>
  <limit lower="-2.6" upper="2.4" effort="45" velocity="1.8"/></joint>
<joint name="j_camera" type="fixed"><parent link="a1"/><child link="camera"/>
  <origin xyz="0.05 -0.04 0.1" rpy="-0.4 0.6 1.0"/></joint>
<joint name="t2" type="prismatic"><parent link="a1"/><child link="a2"/>
  <origin xyz="0.08 0.02 0.3" rpy="0.6 -0.2 0.4"/><axis xyz="0.48 -0.6 0.64"/>
  <limit lower="-0.15" upper="0.25" effort="90" velocity="0.6"/></joint>
<joint name="j_side" type="revolute"><parent link="a2"/><child link="s1"/>
  <origin xyz="0.06 0.02 0.04" rpy="0.5 0.1 -0.3"/><axis xyz="0 0.6 0.8"/>
  <limit lower="-1" upper="1" effort="40" velocity="1.5"/></joint>
<joint name="j_side2" type="prismatic"><parent link="s1"/><child link="s2"/>
  <origin xyz="0.1 0 0" rpy="0 0.2 0"/><axis xyz="1 0 0"/>
  <limit lower="-0.1" upper="0.1" effort="40" velocity="1.5"/></joint>
<joint name="t3" type="continuous"><parent link="a2"/><child link="a3"/>
  <origin xyz="-0.03 0.1 0.18" rpy="-0.9 0.3 0.5"/><axis xyz="1.2 -0.9 2.0"/>
  <limit effort="20" velocity="2.2"/></joint>
<joint name="j_finger" type="revolute"><parent link="a3"/><child link="finger"/>
  <origin xyz="0.03 0 0.08" rpy="0.2 -0.5 0.1"/><axis xyz="0 0 1"/>
  <limit lower="-0.5" upper="0.5" effort="40" velocity="1.5"/></joint>
<joint name="j_pad" type="fixed"><parent link="finger"/><child link="pad"/>
  <origin xyz="0.01 0.02 0.04" rpy="-0.3 0.1 0.6"/></joint>
</robot>"""

#: The tree's links below mount: the frames of the sub-chain's model.
TREE_FRAMES = ["mount", "plate", "a1", "camera", "a2", "s1", "s2", "a3", "finger", "pad"]


def load_string(load_pybullet, text: str, folder: Path, name: str) -> PyBulletRobot:
    path = folder / f"{name}.urdf"
    path.write_text(text)
    return load_pybullet(path)


def dof_indices(robot: phri.Robot, pb: PyBulletRobot) -> list[int]:
    """Where each of the robot's joints is in PyBullet's joint vector (all its movable joints)."""
    names = [p.getJointInfo(pb.body, j, physicsClientId=pb.client)[1].decode() for j in pb.joints]
    return [names.index(n) for n in robot.joint_names]


def world_t_link(pb: PyBulletRobot, link: int) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation) of a link's URDF frame, in double precision; link -1 is the base."""
    if link >= 0:
        p_link, r_link, _, _ = link_frames(pb, link)
        return p_link, r_link
    p_com, quat = p.getBasePositionAndOrientation(pb.body, physicsClientId=pb.client)
    p_in, r_in = inertial_frame(pb, -1)
    r_link = quat_to_matrix(quat) @ r_in.T
    return np.array(p_com) - r_link @ p_in, r_link


def assert_same_joints(robot: phri.Robot, pb: PyBulletRobot, kinds: list[int]) -> list[int]:
    """The robot's joints are PyBullet's of those names, with their types and limits; returns their
    indices in PyBullet's joint vector."""
    dofs = dof_indices(robot, pb)
    for k, d in enumerate(dofs):
        info = p.getJointInfo(pb.body, pb.joints[d], physicsClientId=pb.client)
        assert info[2] == kinds[k], f"{robot.joint_names[k]}: PyBullet joint type {info[2]}"
        lower, upper = info[8], info[9]
        if lower > upper:  # pybullet's encoding of a continuous joint
            assert robot.lower_limits[k] == -np.inf and robot.upper_limits[k] == np.inf
        else:
            assert (robot.lower_limits[k], robot.upper_limits[k]) == (lower, upper)
        assert (robot.effort_limits[k], robot.velocity_limits[k]) == (info[10], info[11])
    return dofs


def assert_matches_pybullet(
    robot: phri.Robot,
    pb: PyBulletRobot,
    base: str,
    rng: np.random.Generator,
    moving_base: int | None = None,
) -> dict[str, float]:
    """Over N_CONFIGS random configurations within limits: every frame's pose, its Jacobian at the frame
    origin and at its link's COM, inverse dynamics and the mass matrix, against PyBullet.

    PyBullet holds the whole tree. Its joints that are not the robot's are at 0 (the model locks
    off-chain joints at 0) and still; joint `moving_base` (above the base: not in the model) is at a
    random angle, so phri's base-frame results are compared with PyBullet's world-frame ones moved into
    the base frame. Returns the worst error of each quantity."""
    dofs = dof_indices(robot, pb)
    frames = [f for f in robot.frame_names if f != base]
    worst = dict.fromkeys(("pose", "pose_f32", "jacobian", "tau", "M"), 0.0)
    qs = random_configurations(robot.lower_limits, robot.upper_limits, rng, N_CONFIGS)
    vmax = robot.velocity_limits
    qds = rng.uniform(-3 * vmax, 3 * vmax, qs.shape)
    qdds = rng.uniform(-10.0, 10.0, qs.shape)
    for q, qd, qdd in zip(qs, qds, qdds, strict=True):
        where = f"q={q.tolist()}"
        full, full_qd, full_qdd = (np.zeros(len(pb.joints)) for _ in range(3))
        full[dofs], full_qd[dofs], full_qdd[dofs] = q, qd, qdd
        if moving_base is not None:
            full[moving_base] = rng.uniform(-3.0, 3.0)
        set_q(pb, full)
        p_base, r_base = world_t_link(pb, pb.links[base])
        # Gravity is along −z of phri's base frame: the comparison needs a base z axis that is vertical.
        assert_close(r_base[:, 2], [0.0, 0.0, 1.0], 1e-12, f"base z axis at {where}")
        assert_close(robot.frame_pose(base, q), np.eye(4), 0.0, f"{base} (the base) pose at {where}")
        for name in frames:
            link = pb.links[name]
            t = robot.frame_pose(name, q)
            p_link, r_link, p_f32, r_f32 = link_frames(pb, link)
            err = max(
                np.abs(t[:3, 3] - r_base.T @ (p_link - p_base)).max(),
                np.abs(t[:3, :3] - r_base.T @ r_link).max(),
            )
            assert err <= ATOL, f"{name} pose at {where}: {err:.3e}"
            worst["pose"] = max(worst["pose"], err)
            # pybullet's own single-precision link frame (fields 4, 5; see the module docstring)
            assert_close(
                t[:3, 3], r_base.T @ (p_f32 - p_base), F32_POSITION_ATOL, f"{name} field 4 at {where}"
            )
            assert_close(t[:3, :3], r_base.T @ r_f32, F32_ROTATION_ATOL, f"{name} field 5 at {where}")
            worst["pose_f32"] = max(worst["pose_f32"], np.abs(t[:3, :3] - r_base.T @ r_f32).max())
            jac = robot.jacobian(name, q)
            rotate = np.kron(np.eye(2), r_base.T)  # world axes -> base axes, for v and ω
            expected = rotate @ pybullet_jacobian(pb, link, np.zeros(3), full)[:, dofs]
            err = np.abs(jac - expected).max()
            assert err <= ATOL, f"{name} Jacobian at {where}: {err:.3e}"
            worst["jacobian"] = max(worst["jacobian"], err)
            com, _ = inertial_frame(pb, link)
            shifted = jac.copy()
            shifted[:3] -= np.cross(t[:3, :3] @ com, jac[3:], axisa=0, axisb=0, axisc=0)
            expected_com = rotate @ pybullet_jacobian(pb, link, com, full)[:, dofs]
            assert_close(shifted, expected_com, ATOL, f"{name} COM Jacobian at {where}")
        tau = np.array(
            p.calculateInverseDynamics(
                pb.body, full.tolist(), full_qd.tolist(), full_qdd.tolist(), physicsClientId=pb.client
            )
        )[dofs]
        err = np.abs(robot.inverse_dynamics(q, qd, qdd) - tau).max()
        assert err <= ATOL, f"τ at {where}, qd={qd.tolist()}, qdd={qdd.tolist()}: {err:.3e}"
        worst["tau"] = max(worst["tau"], err)
        m = np.array(p.calculateMassMatrix(pb.body, full.tolist(), physicsClientId=pb.client))
        err = np.abs(robot.mass_matrix(q) - m[np.ix_(dofs, dofs)]).max()
        assert err <= ATOL, f"M at {where}: {err:.3e}"
        worst["M"] = max(worst["M"], err)
    return worst


def test_mixed_revolute_prismatic_chain_matches_pybullet(load_pybullet, rng, tmp_path: Path):
    text = mixed_chain_urdf()
    robot = phri.Robot.from_urdf_string(text)
    pb = load_string(load_pybullet, text, tmp_path, "mixed")
    assert robot.name == "mixed" and robot.joint_names == ["j1", "j2", "j3", "j4"]
    assert robot.frame_names == ["base", "l1", "l2", "l3", "l4", "tool"]
    assert_same_joints(robot, pb, [p.JOINT_REVOLUTE, p.JOINT_PRISMATIC, p.JOINT_REVOLUTE, p.JOINT_PRISMATIC])
    p_base, r_base = world_t_link(pb, -1)
    assert_close(
        np.hstack([p_base, r_base.ravel()]), np.hstack([np.zeros(3), np.eye(3).ravel()]), 1e-12, "base"
    )
    worst = assert_matches_pybullet(robot, pb, "base", rng)
    print("mixed chain: worst", {k: f"{v:.1e}" for k, v in worst.items()})


def test_sub_chain_of_a_tree_matches_pybullet(load_pybullet, rng, tmp_path: Path):
    """base/tip select mount → a3 out of the tree; links off the chain are lumped into its bodies."""
    text = TREE
    robot = phri.Robot.from_urdf_string(text, base="mount", tip="a3")
    pb = load_string(load_pybullet, text, tmp_path, "tree")
    assert robot.joint_names == ["t1", "t2", "t3"]
    assert sorted(robot.frame_names) == sorted(TREE_FRAMES)  # neither ground nor other: not below mount
    assert_same_joints(robot, pb, [p.JOINT_REVOLUTE, p.JOINT_PRISMATIC, p.JOINT_REVOLUTE])
    assert np.isinf(robot.lower_limits[2]) and np.isinf(robot.upper_limits[2])  # t3 is continuous
    names = [p.getJointInfo(pb.body, j, physicsClientId=pb.client)[1].decode() for j in pb.joints]
    worst = assert_matches_pybullet(robot, pb, "mount", rng, moving_base=names.index("turntable"))
    print("tree sub-chain: worst", {k: f"{v:.1e}" for k, v in worst.items()})


def test_prismatic_axis_that_is_not_a_unit_vector_is_normalized(load_pybullet, rng, tmp_path: Path):
    """URDF axes are unit vectors; phri normalizes one that is not, for prismatic joints as for revolute
    ones, and so do PyBullet's Jacobian, inverse dynamics and mass matrix. PyBullet's getLinkState does
    not: it moves prismatic joint k by q_k·|axis_k| along the unit axis. That disagreement is explained
    here (it vanishes once q is stretched so) rather than hidden by a tolerance."""
    long_axes = ("0.3 0.4 0.866", "-0.2 0.9 0.3", "1.2 -0.9 2.0", "0.5 0.5 0.5")  # prismatic: 0.97, 0.87
    vectors = [np.array(a.split(), dtype=float) for a in long_axes]
    unit_axes = tuple(" ".join(repr(float(x)) for x in v / np.linalg.norm(v)) for v in vectors)
    text = mixed_chain_urdf(long_axes)
    robot = phri.Robot.from_urdf_string(text)
    unit = phri.Robot.from_urdf_string(mixed_chain_urdf(unit_axes))
    qs = random_configurations(robot.lower_limits, robot.upper_limits, rng, N_CONFIGS)
    qds, qdds = rng.uniform(-1, 1, qs.shape), rng.uniform(-5, 5, qs.shape)
    for frame in robot.frame_names:
        assert_close(robot.frame_pose(frame, qs), unit.frame_pose(frame, qs), 1e-15, f"{frame} pose")
        assert_close(robot.jacobian(frame, qs), unit.jacobian(frame, qs), 1e-15, f"{frame} Jacobian")
    assert_close(robot.inverse_dynamics(qs, qds, qdds), unit.inverse_dynamics(qs, qds, qdds), 1e-12, "τ")
    assert_close(robot.mass_matrix(qs), unit.mass_matrix(qs), 1e-13, "M")

    pb = load_string(load_pybullet, text, tmp_path, "long_axes")
    stretch = np.array([1.0, np.linalg.norm(vectors[1]), 1.0, np.linalg.norm(vectors[3])])
    worst_unstretched = 0.0
    for q, qd, qdd in zip(qs, qds, qdds, strict=True):
        where = f"q={q.tolist()}"
        set_q(pb, q)
        for name in robot.frame_names[1:]:
            link = pb.links[name]
            p_link, r_link, _, _ = link_frames(pb, link)
            t = robot.frame_pose(name, q * stretch)
            assert_close(t[:3, 3], p_link, ATOL, f"{name} position (q stretched) at {where}")
            assert_close(t[:3, :3], r_link, ATOL, f"{name} rotation at {where}")
            worst_unstretched = max(
                worst_unstretched, np.abs(robot.frame_pose(name, q)[:3, 3] - p_link).max()
            )
            expected = pybullet_jacobian(pb, link, np.zeros(3), q)
            assert_close(robot.jacobian(name, q), expected, ATOL, f"{name} Jacobian at {where}")
        tau = p.calculateInverseDynamics(
            pb.body, q.tolist(), qd.tolist(), qdd.tolist(), physicsClientId=pb.client
        )
        assert_close(robot.inverse_dynamics(q, qd, qdd), tau, ATOL, f"τ at {where}")
        m = p.calculateMassMatrix(pb.body, q.tolist(), physicsClientId=pb.client)
        assert_close(robot.mass_matrix(q), m, ATOL, f"M at {where}")
    assert worst_unstretched > 1e-3  # the stretch above is what PyBullet's getLinkState does


def rpy_matrix(rpy: str) -> np.ndarray:
    """A URDF origin's rotation: roll, pitch, yaw about the fixed x, y, z axes, R = Rz·Ry·Rx."""
    r, p_, y = (float(v) for v in rpy.split())
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p_), 0, np.sin(p_)], [0, 1, 0], [-np.sin(p_), 0, np.cos(p_)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def origin_rpy(element: ET.Element) -> str:
    origin = element.find("origin")
    return "0 0 0" if origin is None else origin.get("rpy", "0 0 0")


def test_cup_axis_is_link_7_x_axis(load_pybullet, rng, tmp_path: Path):
    """The held cup (cup.urdf, attached at cup_frame by the simulator) is a cylinder, whose axis is its
    geometry frame's z. Through the URDF's origins that axis is +x of link_7, the axis whose tilt the
    coffee feature measures; phri's frames and PyBullet's visual shape agree."""
    from phri.sim.world import CUP_FRAME as SIM_CUP_FRAME
    from phri.sim.world import arm_with_cup_urdf

    assert SIM_CUP_FRAME == CUP_FRAME
    text = arm_with_cup_urdf()
    doc = ET.fromstring(text)
    parent_joint = {j.find("child").get("link"): j for j in doc.iter("joint")}  # type: ignore[union-attr]
    path, name = [], "cup"
    while name != LINK_7:
        path.insert(0, parent_joint[name])
        name = path[0].find("parent").get("link")  # type: ignore[union-attr]
    assert [j.find("child").get("link") for j in path] == [CUP_FRAME, "cup"]  # type: ignore[union-attr]
    r_link7_cup = rpy_matrix(origin_rpy(path[0])) @ rpy_matrix(origin_rpy(path[1]))
    (cup,) = [link for link in doc.iter("link") if link.get("name") == "cup"]
    geometry = {}
    for kind in ("visual", "collision"):
        (element,) = cup.findall(kind)
        assert element.find("geometry/cylinder") is not None, f"the cup's {kind} is not a cylinder"
        geometry[kind] = rpy_matrix(origin_rpy(element))
        axis = r_link7_cup @ geometry[kind] @ np.array([0.0, 0.0, 1.0])
        assert_close(axis, [1.0, 0.0, 0.0], 1e-10, f"the cup's {kind} cylinder axis in link_7's frame")

    robot = phri.Robot.from_urdf_string(text)
    assert robot.joint_names == phri.Robot.jaco2().joint_names
    pb = load_string(load_pybullet, text, tmp_path, "arm_with_cup")
    (visual,) = [
        v for v in p.getVisualShapeData(pb.body, physicsClientId=pb.client) if v[1] == pb.links["cup"]
    ]
    assert visual[2] == p.GEOM_CYLINDER
    com, r_inertial = inertial_frame(pb, pb.links["cup"])  # PyBullet's visual frame is relative to it
    assert_close(
        np.hstack([com, r_inertial.ravel()]), np.hstack([np.zeros(3), np.eye(3).ravel()]), 0.0, "cup COM"
    )
    for q in random_configurations(robot.lower_limits, robot.upper_limits, rng, N_CONFIGS):
        link_7 = robot.frame_pose(LINK_7, q)
        relative = link_7[:3, :3].T @ robot.frame_pose("cup", q)[:3, :3]
        assert_close(relative, r_link7_cup, 1e-12, "the URDF's cup orientation as phri reads it")
        axis = robot.frame_pose("cup", q)[:3, :3] @ geometry["visual"] @ np.array([0.0, 0.0, 1.0])
        assert_close(axis, link_7[:3, 0], 1e-10, f"cup axis vs link_7 x at q={q.tolist()}")
        set_q(pb, q)
        st = p.getLinkState(
            pb.body, pb.links["cup"], computeForwardKinematics=True, physicsClientId=pb.client
        )
        pb_axis = quat_to_matrix(st[1]) @ quat_to_matrix(visual[6]) @ np.array([0.0, 0.0, 1.0])
        assert_close(pb_axis, link_7[:3, 0], 1e-10, f"PyBullet's cylinder axis vs link_7 x at q={q.tolist()}")


# --------------------------------------------------------------------------------------------------
# batching, shapes, dtypes, array-likes

N, NQ = 5, 7


def _calls(robot: phri.Robot):
    """(name, call(q, qd, qdd), single-row output shape) for every q-taking method."""
    return [
        ("frame_pose", lambda q, qd, qdd: robot.frame_pose(END_EFFECTOR, q), (4, 4)),
        ("jacobian", lambda q, qd, qdd: robot.jacobian(LINK_7, q), (6, NQ)),
        ("gravity", lambda q, qd, qdd: robot.gravity(q), (NQ,)),
        ("nonlinear_effects", lambda q, qd, qdd: robot.nonlinear_effects(q, qd), (NQ,)),
        ("inverse_dynamics", lambda q, qd, qdd: robot.inverse_dynamics(q, qd, qdd), (NQ,)),
        ("mass_matrix", lambda q, qd, qdd: robot.mass_matrix(q), (NQ, NQ)),
    ]


CALL_NAMES = ["frame_pose", "jacobian", "gravity", "nonlinear_effects", "inverse_dynamics", "mass_matrix"]


@pytest.fixture
def batch(draw_q, rng):
    qs = draw_q(N)
    return qs, rng.uniform(-1, 1, qs.shape), rng.uniform(-3, 3, qs.shape)


def _call(robot, name):
    return {c[0]: c for c in _calls(robot)}[name]


@pytest.mark.parametrize("name", CALL_NAMES)
def test_batched_call_equals_stacked_single_calls(robot: phri.Robot, rng, batch, name: str):
    _, call, shape = _call(robot, name)
    qs, qds, qdds = batch
    single = [call(q, qd, qdd) for q, qd, qdd in zip(qs, qds, qdds, strict=True)]
    for out in single:
        assert out.shape == shape and out.dtype == np.float64
    batched = call(qs, qds, qdds)
    assert batched.shape == (N, *shape) and batched.dtype == np.float64
    np.testing.assert_array_equal(batched, np.stack(single))


@pytest.mark.parametrize("name", CALL_NAMES)
def test_array_likes_are_accepted(robot: phri.Robot, rng, batch, name: str):
    _, call, shape = _call(robot, name)
    qs, qds, qdds = batch
    expected = call(qs, qds, qdds)
    np.testing.assert_array_equal(call(qs.tolist(), qds.tolist(), qdds.tolist()), expected)
    np.testing.assert_array_equal(call(qs[0].tolist(), qds[0].tolist(), qdds[0].tolist()), expected[0])
    np.testing.assert_array_equal(call(tuple(qs[0]), tuple(qds[0]), tuple(qdds[0])), expected[0])
    ints = np.array([3, 2, 3, 2, 3, 2, 3])
    np.testing.assert_array_equal(
        call(ints.tolist(), [0] * 7, [1] * 7), call(ints.astype(float), np.zeros(7), np.ones(7))
    )
    f32 = qs.astype(np.float32)
    np.testing.assert_array_equal(call(f32, qds, qdds), call(f32.astype(np.float64), qds, qdds))
    empty = call(np.zeros((0, NQ)), np.zeros((0, NQ)), np.zeros((0, NQ)))
    assert empty.shape == (0, *shape) and empty.dtype == np.float64


@pytest.mark.parametrize("name", CALL_NAMES)
def test_strided_and_fortran_ordered_inputs_give_the_same_result(robot: phri.Robot, rng, batch, name: str):
    """Any memory layout of the same (N, 7) values gives the same answer (row k is waypoint k)."""
    _, call, _ = _call(robot, name)
    qs, qds, qdds = batch
    expected = call(qs, qds, qdds)
    np.testing.assert_array_equal(
        call(qs[::-1], qds[::-1], qdds[::-1]), expected[::-1], err_msg="reversed rows"
    )
    wide = np.repeat(qs, 2, axis=1)[:, ::2]  # non-contiguous view
    np.testing.assert_array_equal(call(wide, qds, qdds), expected, err_msg="strided view")
    fq, fqd, fqdd = (np.asfortranarray(a) for a in (qs, qds, qdds))
    np.testing.assert_array_equal(call(fq, fqd, fqdd), expected, err_msg="Fortran-ordered arrays")


def test_outputs_are_fresh_arrays(robot: phri.Robot, batch):
    qs, _, _ = batch
    a = robot.gravity(qs)
    b = robot.gravity(qs)
    assert a.flags.c_contiguous and a.flags.writeable and not np.shares_memory(a, b)


# --------------------------------------------------------------------------------------------------
# bad input: specific exception classes that are ValueErrors and name the argument


@pytest.mark.parametrize(
    "cls", [ex.ShapeError, ex.NonFiniteError, ex.InvalidParameterError, ex.UnknownNameError, ex.UrdfError]
)
def test_argument_errors_are_value_errors(cls):
    assert issubclass(cls, ex.PhriError) and issubclass(cls, ValueError)


BAD_SHAPES = [(), (6,), (8,), (0,), (2, 6), (3, 8), (7, 1), (2, 3, 7), (1, 1, 7)]


@pytest.mark.parametrize("name", CALL_NAMES)
@pytest.mark.parametrize("shape", BAD_SHAPES, ids=str)
def test_wrong_q_shape_raises_shape_error(robot: phri.Robot, rng, name: str, shape):
    _, call, _ = _call(robot, name)
    good = np.full(NQ, 3.0)
    with pytest.raises(ex.ShapeError, match=r"^q must have shape \(7,\) or \(N, 7\), got "):
        call(np.full(shape, 3.0), good, good)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((np.ones(7), np.ones(6), np.ones(7)), r"^qd must have shape \(7,\) or \(N, 7\), got \(6,\)"),
        (
            (np.ones(7), np.ones(7), np.ones((7, 7, 1))),
            r"^qdd must have shape \(7,\) or \(N, 7\), got \(7, 7, 1\)",
        ),
        (
            (np.ones((2, 7)), np.ones((3, 7)), np.ones((2, 7))),
            r"^qd must have shape \(2, 7\) like q, got \(3, 7\)",
        ),
        ((np.ones((2, 7)), np.ones(7), np.ones((2, 7))), r"^qd must have shape \(2, 7\) like q, got \(7,\)"),
        ((np.ones((2, 7)), np.ones((2, 7)), np.ones((4, 7))), r"^qdd must have shape \(2, 7\) like q"),
    ],
)
def test_mismatched_dynamics_arguments_raise_shape_error(robot: phri.Robot, args, message):
    with pytest.raises(ex.ShapeError, match=message):
        robot.inverse_dynamics(*args)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("name", CALL_NAMES)
def test_non_finite_q_raises_non_finite_error(robot: phri.Robot, rng, name: str, bad: float):
    _, call, _ = _call(robot, name)
    good = np.full(NQ, 3.0)
    q = good.copy()
    q[4] = bad
    with pytest.raises(ex.NonFiniteError, match=r"^q must be finite, got .* at index 4$"):
        call(q, good, good)
    qs = np.full((3, NQ), 3.0)
    qs[2, 5] = bad
    with pytest.raises(ex.NonFiniteError, match=r"^q must be finite, got .* at index \(2, 5\)$"):
        call(qs, np.zeros((3, NQ)), np.zeros((3, NQ)))


@pytest.mark.parametrize("arg", ["qd", "qdd"])
def test_non_finite_velocity_or_acceleration_raises(robot: phri.Robot, arg: str):
    values = {"q": np.full(NQ, 3.0), "qd": np.zeros(NQ), "qdd": np.zeros(NQ)}
    values[arg][1] = np.nan
    with pytest.raises(ex.NonFiniteError, match=rf"^{arg} must be finite"):
        robot.inverse_dynamics(**values)


@pytest.mark.parametrize("method", ["frame_pose", "jacobian", "with_payload"])
def test_unknown_frame_raises_unknown_name_error(robot: phri.Robot, method: str):
    call = {
        "frame_pose": lambda: robot.frame_pose("j2s7s300_link_8", np.full(NQ, 3.0)),
        "jacobian": lambda: robot.jacobian("j2s7s300_link_8", np.full(NQ, 3.0)),
        "with_payload": lambda: robot.with_payload("j2s7s300_link_8", 0.3),
    }[method]
    with pytest.raises(
        ex.UnknownNameError, match=r"^frame: unknown frame 'j2s7s300_link_8'; known: .*cup_frame"
    ):
        call()


def test_missing_urdf_path_raises_urdf_error(tmp_path: Path):
    missing = tmp_path / "nowhere" / "robot.urdf"
    with pytest.raises(ex.UrdfError, match=rf"^path: cannot read '{re.escape(str(missing))}'"):
        phri.Robot.from_urdf(missing)


@pytest.mark.parametrize(
    "text",
    [
        "",
        "not xml at all",
        "<robot",
        '<robot name="r"><link name="a"/><joint name="j" type="revolute"><parent link="a"/>'
        '<child link="b"/><axis xyz="0 0 1"/><limit lower="0" upper="1" effort="1" velocity="1"/>'
        "</joint></robot>",
    ],
    ids=["empty", "not-xml", "truncated", "undefined-child-link"],
)
def test_malformed_urdf_raises_urdf_error(text: str, tmp_path: Path):
    with pytest.raises(ex.UrdfError, match=r"^urdf: "):
        phri.Robot.from_urdf_string(text)
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    with pytest.raises(ex.UrdfError, match=rf"^path: '{re.escape(str(path))}'"):
        phri.Robot.from_urdf(path)


def _two_link_urdf(
    mass="1", inertia='ixx="0.01" iyy="0.01" izz="0.01"', origin="0 0 0.1", velocity="1"
) -> str:
    return (
        f'<robot name="r"><link name="a"/><link name="b"><inertial><mass value="{mass}"/>'
        f'<inertia {inertia} ixy="0" ixz="0" iyz="0"/></inertial></link>'
        f'<joint name="j" type="revolute"><parent link="a"/><child link="b"/><origin xyz="{origin}"/>'
        f'<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="{velocity}"/></joint></robot>'
    )


def test_the_two_link_fixture_is_valid() -> None:
    assert phri.Robot.from_urdf_string(_two_link_urdf()).nq == 1


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (_two_link_urdf(mass="nan"), r"link 'b' has a mass that is not a finite mass >= 0 kg \(NaN\)"),
        (_two_link_urdf(mass="-1"), r"link 'b' has a mass that is not a finite mass"),
        (
            _two_link_urdf(inertia='ixx="nan" iyy="0.01" izz="0.01"'),
            r"link 'b' has an inertia that must be finite",
        ),
        (
            _two_link_urdf(inertia='ixx="-1" iyy="0.01" izz="10"'),
            r"link 'b' has an inertia that is not a physical inertia tensor",
        ),
        (_two_link_urdf(origin="nan 0 0"), r"joint 'j' has an origin that is not finite"),
        (_two_link_urdf(velocity="-1"), r"joint 'j' has a velocity limit that is not finite and >= 0"),
        (
            # A cycle beside the root: r is the one root, a and b are each other's parent.
            '<robot name="r"><link name="r"/><link name="a"/><link name="b"/>'
            '<joint name="ab" type="fixed"><parent link="a"/><child link="b"/></joint>'
            '<joint name="ba" type="fixed"><parent link="b"/><child link="a"/></joint></robot>',
            r"the joints form a cycle through link",
        ),
        (
            '<robot name="r"><link name="r"/><link name="a"/><joint name="aa" type="continuous">'
            '<parent link="a"/><child link="a"/><axis xyz="0 0 1"/></joint></robot>',
            r"the joints form a cycle through link 'a'",
        ),
        ('<robot name="r"><link name="a"/><link name="a"/></robot>', r"link 'a' is defined twice"),
        (
            '<robot name="r"><link name="a"/><link name="b"/><link name="c"/>'
            '<joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint>'
            '<joint name="j" type="fixed"><parent link="a"/><child link="c"/></joint></robot>',
            r"joint 'j' is defined twice",
        ),
    ],
    ids=[
        "nan-mass",
        "negative-mass",
        "nan-inertia",
        "unphysical-inertia",
        "nan-origin",
        "negative-velocity",
        "cycle",
        "self-loop",
        "duplicate-link",
        "duplicate-joint",
    ],
)
def test_urdf_numbers_and_structure_are_checked_when_read(text: str, message: str) -> None:
    with pytest.raises(ex.UrdfError, match=rf"^urdf: {message}"):
        phri.Robot.from_urdf_string(text)


def test_tip_not_below_base_raises(robot: phri.Robot):
    text = jaco2_urdf_path().read_text()
    with pytest.raises(ex.InvalidParameterError, match=r"^tip link 'j2s7s300_link_2' is not below the base"):
        phri.Robot.from_urdf_string(text, base=PREFIX + "link_4", tip=PREFIX + "link_2")
    with pytest.raises(ex.InvalidParameterError, match=r"^tip must lie below a movable joint of base"):
        phri.Robot.from_urdf_string(text, base=LINK_7, tip=END_EFFECTOR)


@pytest.mark.parametrize("arg", ["base", "tip"])
def test_unknown_base_or_tip_raises_unknown_name_error(arg: str):
    text = jaco2_urdf_path().read_text()
    with pytest.raises(ex.UnknownNameError, match=rf"^{arg}: unknown link 'nope'; known: "):
        phri.Robot.from_urdf_string(text, **{arg: "nope"})
    with pytest.raises(ex.UnknownNameError, match=rf"^{arg}: unknown link 'nope'"):
        phri.Robot.from_urdf(jaco2_urdf_path(), **{arg: "nope"})


def test_from_urdf_defaults_to_the_shipped_chain(robot: phri.Robot, draw_q):
    default = phri.Robot.from_urdf(jaco2_urdf_path())
    assert default.joint_names == robot.joint_names
    qs = draw_q(10)
    np.testing.assert_array_equal(default.mass_matrix(qs), robot.mass_matrix(qs))


@pytest.mark.parametrize(
    ("kwargs", "cls", "message"),
    [
        ({"mass": -0.3}, ex.InvalidParameterError, r"^mass must be in \[0, 1000\] kg, got -0.3"),
        ({"mass": float("nan")}, ex.InvalidParameterError, r"^mass must be in \[0, 1000\] kg"),
        ({"mass": float("inf")}, ex.InvalidParameterError, r"^mass must be in \[0, 1000\] kg"),
        ({"mass": 0.3, "com": [0.0, 0.0]}, ex.ShapeError, r"^com must have shape \(3,\), got \(2,\)"),
        ({"mass": 0.3, "com": [0.0, np.nan, 0.0]}, ex.NonFiniteError, r"^com must be finite"),
        (
            {"mass": 0.3, "inertia": np.eye(2)},
            ex.ShapeError,
            r"^inertia must have shape \(3, 3\), got \(2, 2\)",
        ),
        (
            {"mass": 0.3, "inertia": np.diag([1.0, np.inf, 1.0])},
            ex.NonFiniteError,
            r"^inertia must be finite",
        ),
    ],
)
def test_bad_payload_raises(robot: phri.Robot, kwargs, cls, message):
    with pytest.raises(cls, match=message):
        robot.with_payload(CUP_FRAME, **kwargs)


def test_random_bad_inputs_raise_phri_errors_never_panics(robot: phri.Robot, rng):
    """A randomized sweep (ruckig-style): odd shapes, NaN/inf, huge values across every method. Either a
    finite result or a PhriError; a PanicException (a BaseException) would escape and fail the test."""
    shapes = [(), (0,), (7,), (6,), (0, 7), (3, 7), (3, 6), (7, 3), (2, 2, 7), (1, 7)]
    specials = [np.nan, np.inf, -np.inf, 1e6, -1e6, 0.0, -0.0]
    outcomes = {"ok": 0, "error": 0}
    for _ in range(600):
        args = []
        for _ in range(3):
            shape = shapes[rng.integers(len(shapes))]
            a = rng.uniform(-10, 10, shape)
            if a.size and rng.random() < 0.3:
                a.flat[rng.integers(a.size)] = specials[rng.integers(len(specials))]
            args.append(a)
        name, call, _ = _calls(robot)[rng.integers(len(CALL_NAMES))]
        try:
            out = call(*args)
        except ex.PhriError:
            outcomes["error"] += 1
        else:
            outcomes["ok"] += 1
            assert np.isfinite(out).all(), (
                f"{name} returned non-finite values for {[a.tolist() for a in args]}"
            )
    assert outcomes["ok"] > 0 and outcomes["error"] > 0


def test_check_limits(robot: phri.Robot, draw_q):
    robot.check_limits(draw_q(50))
    q = np.full(NQ, np.pi)
    q[3] = 0.1
    with pytest.raises(
        ex.InvalidParameterError, match=r"^q has \[3\] = 0.1, outside the limits .* 'j2s7s300_joint_4'"
    ):
        robot.check_limits(q)
    # continuous joints have no limits
    robot.check_limits(np.array([-50.0, np.pi, 50.0, np.pi, -50.0, np.pi, 50.0]))


def test_random_configurations_helper_respects_limits(robot: phri.Robot):
    qs = random_configurations(robot.lower_limits, robot.upper_limits, np.random.default_rng(0), 1000)
    limited = np.isfinite(robot.lower_limits)
    assert (qs[:, limited] >= robot.lower_limits[limited]).all()
    assert (qs[:, limited] <= robot.upper_limits[limited]).all()
    assert (qs[:, ~limited] >= 0).all() and (qs[:, ~limited] < 2 * np.pi).all()


@pytest.mark.parametrize(
    "bad", ["abc", ["a"] * 7, [[1.0, 2.0], [3.0]], object()], ids=["str", "strs", "ragged", "obj"]
)
def test_inputs_that_are_not_numbers_are_a_type_error_naming_the_argument(robot: phri.Robot, bad) -> None:
    with pytest.raises(
        TypeError, match=r"^argument 'q': expected real numbers \(an array, a list or a number\), got "
    ):
        robot.gravity(bad)
    with pytest.raises(TypeError, match=r"^argument 'waypoints': expected real numbers"):
        phri.TimedTrajectory(bad, 15.0)


# --------------------------------------------------------------------------------------------------
# what a robot description carries


def _description(tmp_path: Path, carried: str, extra: str = "") -> Path:
    """A copy of the shipped JACO2 description in `tmp_path` with `carried` as its [carried] tables."""
    shipped = Path(str(importlib.resources.files("phri").joinpath("robots/jaco2")))
    for name in ("j2s7s300.urdf", "cup.urdf"):
        (tmp_path / name).write_text((shipped / name).read_text())
    text = (shipped / "robot.toml").read_text()
    head = text[: text.index("[carried.cup]")]
    path = tmp_path / "robot.toml"
    path.write_text(extra + head + carried)
    return path


def test_a_description_attaches_what_the_robot_carries(tmp_path: Path) -> None:
    tray = '<robot name="tray"><link name="tray"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.01"/></geometry></collision></link></robot>'  # noqa: E501
    (tmp_path / "tray.urdf").write_text(tray)
    both = _description(
        tmp_path,
        '[carried.cup]\nurdf = "cup.urdf"\nframe = "j2s7s300_cup_frame"\n'
        '[carried.tray]\nurdf = "tray.urdf"\nframe = "j2s7s300_link_7"\n',
    )
    robot = phri.Robot.from_description(both)
    assert robot.collision_bodies[-2:] == ["cup", "tray"] and robot.cup_frame == CUP_FRAME
    centers, radii, frame = robot.collision_spheres("tray")
    assert frame == LINK_7 and np.allclose(centers[:, 2], 0.05) and len(radii) > 1
    none = _description(tmp_path, "", extra='cup_frame = "j2s7s300_cup_frame"\n')
    bare = phri.Robot.from_description(none)
    assert "cup" not in bare.collision_bodies and bare.cup_frame == CUP_FRAME
    assert phri.Robot.jaco2().collision_bodies[-1] == "cup"


@pytest.mark.parametrize(
    ("carried", "extra", "error", "message"),
    [
        ("carried = 3\n", "", ex.ConfigError, "key 'carried' must be a table of object tables"),
        ("[carried]\ncup = 1\n", "", ex.ConfigError, "key 'carried.cup' must be a table with urdf and frame"),
        ('[carried.cup]\nurdf = "cup.urdf"\n', "", ex.ConfigError, "missing key 'carried.cup.frame'"),
        (
            '[carried.cup]\nurdf = "cup.urdf"\nframe = "j2s7s300_cup_frame"\nmass = 0.3\n',
            "", ex.ConfigError, "unknown key 'carried.cup.mass' in table [carried.cup]",
        ),
        (
            '[carried.cup]\nurdf = "mug.urdf"\nframe = "j2s7s300_cup_frame"\n',
            "", ex.ConfigError, "key 'carried.cup.urdf': cannot read",
        ),
        (
            '[carried.cup]\nurdf = "j2s7s300.urdf"\nframe = "j2s7s300_cup_frame"\n',
            "", ex.UrdfError,
            "key 'carried.cup.urdf': joint 'j2s7s300_joint_1' of an attached object must be fixed",
        ),
        (
            '[carried.cup]\nurdf = "cup.urdf"\nframe = "j2s7s300_hand"\n',
            "", ex.UnknownNameError, "key 'carried.cup.frame': frame: unknown frame 'j2s7s300_hand'",
        ),
        (
            '[carried.cup]\nurdf = "cup.urdf"\nframe = "j2s7s300_cup_frame"\n',
            'cup_frame = "j2s7s300_link_7"\n', ex.ConfigError,
            "key 'cup_frame' must be left out or the frame of [carried.cup] ('j2s7s300_cup_frame')",
        ),
    ],
)  # fmt: skip
def test_bad_carried_tables_name_the_file_and_key(tmp_path: Path, carried, extra, error, message) -> None:
    path = _description(tmp_path, carried, extra)
    with pytest.raises(error, match="^" + re.escape(f"{path}: ") + ".*" + re.escape(message)):
        phri.Robot.from_description(path)


# --------------------------------------------------------------------------------------------------
# what a URDF may cost (issue 16 #14)


def test_a_fifo_or_folder_is_refused_at_once_not_read(tmp_path: Path) -> None:
    import os
    import threading

    fifo = tmp_path / "robot.urdf"
    os.mkfifo(fifo)
    result: list[BaseException | None] = []

    def load() -> None:
        try:
            phri.Robot.from_urdf(fifo)
            result.append(None)
        except BaseException as e:  # noqa: BLE001 - handed to the test thread
            result.append(e)

    thread = threading.Thread(target=load, daemon=True)
    thread.start()
    thread.join(10)
    if thread.is_alive():  # the old reader blocked here for ever; unblock it before failing
        with open(fifo, "w"):
            pass
        pytest.fail("Robot.from_urdf blocked on a FIFO")
    assert isinstance(result[0], ex.UrdfError)
    assert "not a regular file (a FIFO, socket or device)" in str(result[0])
    with pytest.raises(ex.UrdfError, match=r"^path: cannot read .*it is a folder"):
        phri.Robot.from_urdf(tmp_path)
    robot = phri.Robot.jaco2()
    with pytest.raises(ex.UrdfError, match="not a regular file"):
        robot.with_attached_urdf("cup", "j2s7s300_link_7", fifo)


@pytest.mark.parametrize("depth", [65, 16_000, 200_000])
def test_deeply_nested_xml_is_refused_in_linear_time(depth: int, tmp_path: Path) -> None:
    """urdf-rs took quadratic time in the depth and overflowed its stack (a segfault) at ~16,000."""
    doc = '<robot name="r"><link name="a"/>' + "<x>" * depth + "</x>" * depth + "</robot>"
    nested = r"^urdf: not a valid URDF document \(elements nested more than 64 deep"
    with pytest.raises(ex.UrdfError, match=nested):
        phri.Robot.from_urdf_string(doc)
    path = tmp_path / "deep.urdf"
    path.write_text(doc)
    with pytest.raises(ex.UrdfError, match=rf"^path: '{re.escape(str(path))}': .*nested more than 64 deep"):
        phri.Robot.jaco2().with_attached_urdf("cup", "j2s7s300_link_7", path)


def test_a_robot_description_larger_than_the_limit_is_refused(tmp_path: Path) -> None:
    big = tmp_path / "big.urdf"
    with open(big, "wb") as f:
        f.write(b'<robot name="r"><link name="a"/>')
        f.write(b" " * (32 << 20))
        f.write(b"</robot>")
    with pytest.raises(ex.UrdfError, match=r"larger than a robot description may be \(33554432 bytes\)"):
        phri.Robot.from_urdf(big)


def _one_cylinder_link(radius: str, length: str) -> str:
    return (
        '<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/>'
        '<inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial>'
        f'<collision><geometry><cylinder radius="{radius}" length="{length}"/></geometry></collision></link>'
        '<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
    )


def test_a_cylinder_far_longer_than_thick_is_covered_by_a_bounded_number_of_spheres() -> None:
    """Found by the URDF proptest: the sphere count overflowed (a panic in debug builds, in release
    a link silently left without spheres, so collision checks ignored it)."""
    robot = phri.Robot.from_urdf_string(_one_cylinder_link("1e-300", "1"))
    centers, radii, _ = robot.collision_spheres("b")
    assert 1 <= len(radii) <= 64
    assert np.ptp(centers[:, 2]) + 2 * radii.max() >= 1.0  # the spheres still span the cylinder
    with pytest.raises(ex.UrdfError, match=r"not a distance in \(0, 1000\] m"):
        phri.Robot.from_urdf_string(_one_cylinder_link("1e200", "1"))


def test_urdf_parsing_releases_the_gil() -> None:
    """Other Python threads run while a description is read (it held the GIL: issue 16 #14). The
    other thread notes the time as it runs; with the GIL held it could note none while the call is
    in the middle of its work."""
    import threading
    import time

    text = (importlib.resources.files("phri") / "robots" / "jaco2" / "j2s7s300.urdf").read_text()
    big = text.replace("<robot", "<!--" + "x" * (20 << 20) + "-->\n<robot", 1)
    seen: list[float] = []
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            seen.append(time.perf_counter())
            for _ in range(200):
                pass

    thread = threading.Thread(target=spin)
    thread.start()
    try:
        time.sleep(0.05)
        start = time.perf_counter()
        phri.Robot.from_urdf_string(big)
        end = time.perf_counter()
    finally:
        stop.set()
        thread.join()
    margin = 0.2 * (end - start)
    inside = [t for t in seen if start + margin < t < end - margin]
    assert end - start > 0.05, "the parse was too short to tell"
    assert inside, f"the other thread did not run during the {end - start:.2f} s parse"
