"""Attitude conventions: round trips, orthonormality, and the documented error convention."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pospp import rotation
from pospp.nav import _kernels

angles = st.tuples(
    st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(0.0, 6.28)
)


@settings(max_examples=200, deadline=None)
@given(angles)
def test_euler_quat_dcm_round_trips(rpy):
    rpy = np.array(rpy)
    c = rotation.dcm_from_euler(rpy)
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(c) - 1.0) < 1e-12
    q = rotation.quat_from_euler(rpy)
    np.testing.assert_allclose(rotation.dcm_from_quat(q), c, atol=1e-12)
    back = rotation.euler_from_dcm(c)
    assert rotation.angle_between_rad(rotation.dcm_from_euler(back), c) < 1e-9


def test_euler_definition_is_zyx_ned_frd():
    # Yaw 90 deg: the body x axis (forward) points east.
    c = rotation.dcm_from_euler([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(c @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # Pitch up 10 deg: forward axis has a negative down component.
    c = rotation.dcm_from_euler([0.0, np.radians(10.0), 0.0])
    assert (c @ [1, 0, 0])[2] < 0
    # Roll right 10 deg: the body y axis (right) points partly down.
    c = rotation.dcm_from_euler([np.radians(10.0), 0.0, 0.0])
    assert (c @ [0, 1, 0])[2] > 0


@settings(max_examples=100, deadline=None)
@given(angles, st.tuples(*[st.floats(-1e-3, 1e-3)] * 3))
def test_attitude_error_convention(rpy, phi):
    c_true = rotation.dcm_from_euler(np.array(rpy))
    phi = np.array(phi)
    c_hat = rotation.dcm_from_rotvec(-phi) @ c_true  # = (I - [phi x]) C to first order
    np.testing.assert_allclose(rotation.attitude_error_n_rad(c_hat, c_true), phi, atol=1e-14)


def test_heading_error_sign():
    c_true = rotation.dcm_from_euler([0.0, 0.0, 1.0])
    c_hat = rotation.dcm_from_euler([0.0, 0.0, 1.0 + 1e-4])  # computed yaw too large
    phi = rotation.attitude_error_n_rad(c_hat, c_true)
    assert abs(phi[2] + 1e-4) < 1e-12  # phi_D = -(yaw_hat - yaw)


@settings(max_examples=100, deadline=None)
@given(st.tuples(*[st.floats(-2.0, 2.0)] * 3), angles)
def test_kernel_quaternion_helpers_match_scipy_path(rv, rpy):
    q = np.array(_kernels.quat_from_rotvec(*rv))
    np.testing.assert_allclose(
        rotation.dcm_from_quat(q), rotation.dcm_from_rotvec(np.array(rv)), atol=1e-12
    )
    p = rotation.quat_from_euler(np.array(rpy))
    prod = np.array(_kernels.quat_mul(*p, *q))
    np.testing.assert_allclose(prod, rotation.quat_multiply(p, q), atol=1e-14)
    c = np.empty((3, 3))
    _kernels.dcm_from_quat_into(p, c)
    np.testing.assert_allclose(c, rotation.dcm_from_quat(p), atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(st.floats(-12.0, -3.0), st.tuples(*[st.floats(-1.0, 1.0)] * 3))
def test_kernel_quaternion_series_branch_is_exact(log10_angle, axis):
    # below 1e-6 rad^2 the kernel uses the 4th-order series of cos(a/2), sin(a/2)/a
    axis = np.array(axis)
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.3, -0.5, 0.8])
    rv = axis / np.linalg.norm(axis) * 10.0**log10_angle * 0.999
    q = np.array(_kernels.quat_from_rotvec(*rv))
    np.testing.assert_allclose(q, rotation.quat_from_rotvec(rv), rtol=0, atol=2e-16)


def test_roll_error_sign():
    # level, heading north: a computed roll too small by a is phi_N = +a (docs/method.md)
    c_true = rotation.dcm_from_euler([0.0, 0.0, 0.0])
    c_hat = rotation.dcm_from_euler([-1e-4, 0.0, 0.0])
    phi = rotation.attitude_error_n_rad(c_hat, c_true)
    np.testing.assert_allclose(phi, [1e-4, 0.0, 0.0], atol=1e-12)
