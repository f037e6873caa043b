"""Inverse kinematics round trip through MuJoCo's own forward kinematics."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.control import ik


def test_round_trip_through_mujoco(mujoco_sim):
    model, layout = mujoco_sim.model, mujoco_sim.layout
    data = mujoco.MjData(model)
    hip = model.body("l_hip").id
    ankle = model.site("l_ankle").id
    xs, zs = np.meshgrid(np.linspace(-0.04, 0.04, 11), np.linspace(0.17, 0.23, 11))
    angles = jax.vmap(ik.leg_joint_angles, in_axes=(0, 0, None))(
        jnp.asarray(xs.ravel()), jnp.asarray(zs.ravel()), layout.geometry)
    worst = 0.0
    for (x, z), leg in zip(zip(xs.ravel(), zs.ravel()), np.asarray(angles)):
        data.qpos[:] = model.qpos0
        for k, actuator in enumerate(layout.left_leg_ctrl):
            data.qpos[model.jnt_qposadr[model.actuator_trnid[actuator, 0]]] = leg[k]
        mujoco.mj_kinematics(model, data)
        rel = data.site_xpos[ankle] - data.xpos[hip]   # pelvis at the identity pose
        worst = max(worst, abs(rel[0] - x), abs(rel[1]), abs(-rel[2] - z))
        sole_up = data.xmat[model.body("l_foot").id].reshape(3, 3)[:, 2]
        np.testing.assert_allclose(sole_up, [0, 0, 1], atol=1e-5)
    assert worst < 1e-4


def test_forward_kinematics_inverts_ik():
    x, z = jnp.float32(0.02), jnp.float32(0.2)
    np.testing.assert_allclose(ik.ankle_position(ik.leg_joint_angles(x, z)), [0.02, 0.2], atol=1e-6)
