"""phri.Robot: contracts (shapes, dtypes, batching, exceptions) and agreement with PyBullet.

PyBullet reads the same URDF, so any rounding in the file is shared and the two agree to machine
precision: the brief's contract is 1e-6, and double-precision quantities are held to ATOL = 1e-9
(observed: ~1e-14). The exception is getLinkState's worldLinkFrame fields (4, 5): pybullet composes them
client-side in single precision (every value returned is an exact float32, asserted below), so the
position is off by up to ~1e-7 m and the rotation entries by up to ~10 float32 ulps (1.2e-6 observed
over 2000 configurations). Those fields get a float32-sized tolerance; the exact check of every link
frame composes the double-precision COM frame (fields 0, 1) with the local inertial frame (2, 3).
"""

from __future__ import annotations

import re
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


FK_VECTORS = [  # jaco2_model.md, "Forward-kinematics test vectors"
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
        ({"mass": -0.3}, ex.InvalidParameterError, r"^mass must be a finite mass >= 0 kg, got -0.3"),
        ({"mass": float("nan")}, ex.InvalidParameterError, r"^mass must be a finite mass"),
        ({"mass": float("inf")}, ex.InvalidParameterError, r"^mass must be a finite mass"),
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
