"""Property tests for jaxcal.rotation (hypothesis): the invariants every rotation must satisfy."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxcal import rotation as rot

settings.register_profile("jaxcal", deadline=None, max_examples=60, derandomize=True)
settings.load_profile("jaxcal")
# Hypothesis tests that take the x64 fixture: one fixture context for all examples (intended).
X64_HYP = settings(suppress_health_check=[HealthCheck.function_scoped_fixture])

finite = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite).map(lambda t: np.asarray(t, dtype=np.float64))
tiny = st.floats(min_value=-1e-3, max_value=1e-3, allow_nan=False)
small_vec3 = st.tuples(tiny, tiny, tiny).map(lambda t: np.asarray(t, dtype=np.float64))

# Jitted once per module: eager jacobians and gradients re-trace op by op at every call.
exp64 = jax.jit(rot.exp_so3)
log_jit = jax.jit(rot.log_so3)
exp_derivatives = jax.jit(lambda z: (jax.jacfwd(rot.exp_so3)(z), jax.jacrev(rot.exp_so3)(z),
                                     jax.hessian(lambda v: jnp.sum(rot.exp_so3(v)))(z)))
grad_weighted = jax.jit(jax.grad(lambda u: jnp.sum(rot.exp_so3(u) @ jnp.arange(3.0))))


def _exp(v):
    """Exp in float64: call from a test that takes the x64 fixture."""
    return np.asarray(exp64(jnp.asarray(v, dtype=jnp.float64)))


@X64_HYP
@given(vec3)
def test_exp_is_orthonormal_with_unit_determinant(x64, v):
    r = _exp(v)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(r) - 1.0) < 1e-12


@X64_HYP
@given(vec3)
def test_exp_of_negative_is_inverse(x64, v):
    np.testing.assert_allclose(_exp(v) @ _exp(-v), np.eye(3), atol=1e-12)


@X64_HYP
@given(vec3)
def test_exp_matches_rodrigues_textbook_form(x64, v):
    """Against the thesis's element-wise eq. 4.3 evaluated independently in numpy."""
    t = np.linalg.norm(v)
    if t < 1e-6:
        return
    x, y, z = v / t
    c, s = np.cos(t), np.sin(t)
    ref = np.array(
        [
            [c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
            [x * y * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
            [x * z * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)],
        ]
    )
    np.testing.assert_allclose(_exp(v), ref, atol=1e-12)


@X64_HYP
@given(small_vec3)
def test_small_angle_agrees_with_first_order(x64, v):
    # hat of the float32-rounded v, as before the x64 fixture (only Exp ran in float64)
    err = np.abs(_exp(v) - (np.eye(3) + np.asarray(rot.hat(jnp.asarray(v, jnp.float32))))).max()
    assert err <= 0.5 * float(v @ v) + 1e-15


def test_exp_zero_is_identity_with_finite_exact_gradient():
    for dtype in (jnp.float32, jnp.float64):
        # Local on purpose: the float32 pass checks the default mode (x64 off), the float64 pass
        # needs x64 on; the x64 fixture would set one mode for both passes.
        with jax.enable_x64(dtype == jnp.float64):
            z = jnp.zeros(3, dtype=dtype)
            np.testing.assert_array_equal(np.asarray(rot.exp_so3(z)), np.eye(3))
            jac, jac_rev, hess = map(np.asarray, exp_derivatives(z))  # jac: (3, 3, 3), d R_ij / d v_k
            assert np.all(np.isfinite(jac)) and np.all(np.isfinite(jac_rev))
            # d Exp / d v_k at 0 is the generator hat(e_k).
            for k in range(3):
                np.testing.assert_allclose(jac[:, :, k], np.asarray(rot.hat(jnp.eye(3)[k])), atol=1e-7)
            assert np.all(np.isfinite(hess))


@given(vec3)
def test_gradient_is_finite_everywhere(v):
    g = grad_weighted(jnp.asarray(v, jnp.float32))
    assert np.all(np.isfinite(np.asarray(g)))


@X64_HYP
@given(vec3)
def test_log_inverts_exp(x64, v):
    t = np.linalg.norm(v)
    if t > np.pi - 1e-3:  # log returns the representative with angle in [0, pi]
        v = v / t * (t % (2 * np.pi))
        t = np.linalg.norm(v)
        if t > np.pi - 1e-3:
            v = v / t * (t - 2 * np.pi)
    back = np.asarray(log_jit(exp64(jnp.asarray(v))))
    np.testing.assert_allclose(back, v, atol=1e-9)


@X64_HYP
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_exp_of_log_is_identity_map_on_so3(x64, seed):
    r = rot.random_rotation(jax.random.PRNGKey(seed))
    np.testing.assert_allclose(np.asarray(exp64(log_jit(r))), np.asarray(r), atol=1e-10)


def test_log_near_pi_and_at_identity(x64):
    for v in (jnp.array([np.pi, 0, 0]), jnp.array([0, 1e-9, 0]), jnp.zeros(3)):
        np.testing.assert_allclose(np.asarray(log_jit(exp64(v))), np.asarray(v), atol=1e-9)


@X64_HYP
@given(vec3, vec3)
def test_quaternion_round_trip(x64, a, b):
    r = exp64(jnp.asarray(a)) @ exp64(jnp.asarray(b))
    np.testing.assert_allclose(np.asarray(rot.matrix_from_quat(rot.quat_from_matrix(r))), np.asarray(r), atol=1e-12)


def test_compose_is_ordered_product(x64):
    vs = jax.random.normal(jax.random.PRNGKey(0), (5, 3))
    rs = exp64(vs)
    ref = rs[0] @ rs[1] @ rs[2] @ rs[3] @ rs[4]
    np.testing.assert_allclose(np.asarray(rot.compose(rs)), np.asarray(ref), atol=1e-12)
    # Constant rate: the product of N equal steps is one step of N times the angle.
    w = jnp.array([0.3, -0.2, 0.1])
    np.testing.assert_allclose(
        np.asarray(rot.total_rotation(jnp.tile(w, (100, 1)), 0.01)), np.asarray(exp64(w)), atol=1e-12
    )


def test_specific_force_follows_physical_convention(x64):
    """f_n = R_n^T g_up with R_{n+1} = R_n Exp(w_n dt): propagation agrees with orientation."""
    k1, k2 = jax.random.split(jax.random.PRNGKey(3))
    r0 = rot.random_rotation(k1)
    w = 0.5 * jax.random.normal(k2, (50, 3))
    up = jnp.array([0.0, 0.0, 1.0])  # at rest the accelerometer reads +1 g along world up
    f = rot.propagate_specific_force(r0.T @ up, w, 0.01)
    rs = rot.integrate_orientation(r0, w, 0.01)
    np.testing.assert_allclose(np.asarray(f), np.asarray(jnp.einsum("nji,j->ni", rs, up)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(f), axis=1), 1.0, atol=1e-12)
    # A rotation about world up leaves the reading unchanged.
    f_yaw = rot.propagate_specific_force(up, jnp.tile(jnp.array([0.0, 0.0, 1.0]), (10, 1)), 0.1)
    np.testing.assert_allclose(np.asarray(f_yaw), np.tile(np.asarray(up), (11, 1)), atol=1e-12)
    # After a +90 deg roll about body x, body y points up: the reading moves to +1 g on y.
    f_roll = rot.propagate_specific_force(up, jnp.array([[np.pi / 2, 0.0, 0.0]]), 1.0)
    np.testing.assert_allclose(np.asarray(f_roll[-1]), [0.0, 1.0, 0.0], atol=1e-12)


def test_slerp_pairs_follows_the_rotation_about_the_axis():
    """Closed form: from the identity to a turn of theta about an axis, slerp at u is the turn u theta
    about it; the far-hemisphere sign of q1 is the same rotation; equal quaternions give q0 exactly."""
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    u = np.linspace(0.0, 1.0, 11)
    for theta in (1e-9, 1e-3, 1.0, 3.0):
        q0 = np.tile([1.0, 0.0, 0.0, 0.0], (u.size, 1))
        q1 = np.tile(np.r_[np.cos(theta / 2), np.sin(theta / 2) * axis], (u.size, 1))
        want = np.c_[np.cos(u * theta / 2), np.sin(u * theta / 2)[:, None] * axis]
        np.testing.assert_allclose(rot.slerp_pairs(q0, q1, u), want, atol=1e-15)
        np.testing.assert_allclose(rot.slerp_pairs(q0, -q1, u), want, atol=1e-15)
    q = np.tile(np.array([0.5, 0.5, -0.5, 0.5]), (u.size, 1))
    np.testing.assert_array_equal(rot.slerp_pairs(q, q, u), q)


def test_quaternion_product_is_the_matrix_product(x64):
    """``R(a ⊗ b) = R(a) R(b)`` (Hamilton, scalar first), for random unit quaternions."""
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((2, 50, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    lhs = np.asarray(rot.matrix_from_quat(rot.quat_mul(jnp.asarray(a), jnp.asarray(b))))
    rhs = np.asarray(rot.matrix_from_quat(jnp.asarray(a))) @ np.asarray(rot.matrix_from_quat(jnp.asarray(b)))
    np.testing.assert_allclose(lhs, rhs, atol=1e-14)


# ---------------------------------------------------------------------------------------------------
# propagate_specific_force's closed-form tangent against autodiff of an independent loop
# ---------------------------------------------------------------------------------------------------


def _loop_propagation(f0, w, dt):
    """A second implementation (here on purpose): the plain loop ``f_{n+1} = Exp(w_n dt)^T f_n``,
    differentiated by JAX's own rules through ``lax.scan`` and ``exp_so3``."""
    def step(f, r):
        f_next = r.T @ f
        return f_next, f_next

    _, fs = jax.lax.scan(step, f0, rot.exp_so3(w * dt))
    return jnp.concatenate([f0[None], fs], axis=0)


# one compile each: 40 rates, dt a traced argument
_jac_closed = jax.jit(lambda f0, w, dt, u, e: jax.jacfwd(lambda *a: rot.propagate_specific_force(*a, unroll=u, elementwise=e), argnums=(0, 1, 2))(f0, w, dt), static_argnums=(3, 4))
_jac_closed_rev = jax.jit(jax.jacrev(rot.propagate_specific_force, argnums=(0, 1, 2)))
_jac_loop = jax.jit(jax.jacfwd(_loop_propagation, argnums=(0, 1, 2)))


@settings(max_examples=20, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(0, 2**31 - 1), st.sampled_from([0.0, 1e-5, 1e-2, 1.0, 30.0]), st.booleans())
def test_propagation_tangent_is_the_derivative_of_the_loop(x64, seed, scale, elementwise):
    """The closed-form tangent (forward and reverse mode, any unroll, both product forms) equals
    JAX's autodiff of the plain loop, at rates from 0 (every step on the small-angle branch) to
    30 rad/s (0.3 rad per step); the primal of the dot form equals the loop bit for bit.
    Deviation measured: 1.3e-15 of max(1, max |J|) over 150 cases (30 seeds x the 5 scales, both
    forms and reverse mode); the tolerance 1e-12 leaves room for other CPUs' rounding."""
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(seed), 3)
    w = scale * jax.random.normal(k1, (40, 3))
    w = w.at[7].set(0.0)  # a stationary sample among moving ones
    f0 = jax.random.normal(k2, (3,))
    dt = jnp.asarray(0.01)
    want = _jac_loop(f0, w, dt)
    for got in (_jac_closed(f0, w, dt, 4, elementwise), _jac_closed_rev(f0, w, dt)):
        for g, e in zip(got, want):
            np.testing.assert_allclose(np.asarray(g), np.asarray(e), rtol=1e-12, atol=1e-12 * max(1.0, float(jnp.max(jnp.abs(e)))))
    assert bool(jnp.array_equal(rot.propagate_specific_force(f0, w, dt, unroll=4), _loop_propagation(f0, w, dt)))


@X64_HYP
@given(vec3, vec3)
def test_right_jacobian_is_the_derivative_of_exp(x64, v, d):
    """``Exp(v)^T Exp(v + h d) = Exp(h J_r(v) d) + O(h^2)``: a central difference of ``Log`` recovers
    ``J_r(v) d`` (h = 1e-6); ``J_r(0) = I``. Measured over 300 draws (a third near 0): 5.9e-11 of
    max(1, |d|), the rounding of a difference over 2h; tolerance 1e-7."""
    h = 1e-6
    if np.linalg.norm(v) > 3.0:  # stay away from the cut at pi, where Log jumps
        v = v * (3.0 / np.linalg.norm(v))
    jr = np.asarray(rot.right_jacobian_so3(jnp.asarray(v)))
    plus = np.asarray(log_jit(jnp.asarray(_exp(v).T @ _exp(v + h * d))))
    minus = np.asarray(log_jit(jnp.asarray(_exp(v).T @ _exp(v - h * d))))
    np.testing.assert_allclose((plus - minus) / (2 * h), jr @ d, atol=1e-7 * max(1.0, np.linalg.norm(d)))
    np.testing.assert_array_equal(np.asarray(rot.right_jacobian_so3(jnp.zeros(3))), np.eye(3))


def test_angle_between_is_exact_at_small_and_near_pi_angles(x64):
    """``angle_between`` against the angle that built the vectors, from 1e-12 rad to pi - 1e-9, at any
    lengths: arccos of the normalised dot product reads 0 or 1.5e-8 rad below about 1e-8 rad."""
    th = np.concatenate([np.logspace(-12, 0, 13), np.pi - np.logspace(-9, -1, 9)])
    a = np.tile([[2.0, 0.0, 0.0]], (len(th), 1))
    b = 0.5 * np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], 1)
    got = np.asarray(rot.angle_between(jnp.asarray(a), jnp.asarray(b)))
    # measured 1.4e-16; 10 ulp allowed for the platform's atan2 (arccos: 0 below 1e-8 rad, 1e-7 read as 0.9996e-7)
    np.testing.assert_allclose(got, th, rtol=2e-15)
    assert float(rot.angle_between(jnp.asarray(a[0]), jnp.asarray(a[0]))) == 0.0
