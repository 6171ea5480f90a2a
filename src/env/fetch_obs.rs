//! The Fetch observation: `MujocoFetchEnv.generate_mujoco_observations` and `_get_obs`.
//!
//! Velocities come from the site Jacobian times qvel (`mujoco_utils.get_site_xvelp/xvelr`), not
//! from `mj_objectVelocity`: the two differ (frame and stale-kinematics effects), and datasets
//! were recorded with the former. numpy multiplies with BLAS, whose summation order we cannot
//! see, so these agree with Python to ~1e-17 rather than bit for bit.

use super::FetchEnv;
use crate::env::Obs;

/// `rotations._EPS4`: below this `cy` the Euler decomposition is treated as gimbal-locked.
const EPS4: f64 = f64::EPSILON * 4.0;

/// `rotations.mat2euler` for one row-major 3×3 matrix: the static-axes xyz Euler angles
/// gymnasium-robotics reports (note the negated `arctan2`s).
pub(crate) fn mat2euler(m: &[f64; 9]) -> [f64; 3] {
    let at = |r: usize, c: usize| m[3 * r + c];
    let cy = (at(2, 2) * at(2, 2) + at(1, 2) * at(1, 2)).sqrt();
    let y = -(-at(0, 2)).atan2(cy);
    if cy > EPS4 {
        [-at(1, 2).atan2(at(2, 2)), y, -at(0, 1).atan2(at(0, 0))]
    } else {
        [0.0, y, -(-at(1, 0)).atan2(at(1, 1))]
    }
}

/// `J @ qvel` for a row-major 3×nv Jacobian.
fn jac_times(jac: &[f64], qvel: &[f64]) -> [f64; 3] {
    let nv = qvel.len();
    std::array::from_fn(|r| jac[r * nv..(r + 1) * nv].iter().zip(qvel).map(|(j, v)| j * v).sum())
}

impl FetchEnv {
    /// (linear, angular) velocity of a site times dt. The angular part is only computed when
    /// asked for, as Python only asks for the object's.
    fn site_vel_dt(&self, site: usize, angular: bool) -> ([f64; 3], [f64; 3]) {
        let (jacp, jacr) = self.data.jac_site(true, angular, site);
        let qvel = self.data.qvel();
        let velp = jac_times(&jacp, qvel).map(|v| v * self.dt);
        let velr = if angular { jac_times(&jacr, qvel).map(|v| v * self.dt) } else { [0.0; 3] };
        (velp, velr)
    }

    /// The observation dict. Layout (25): grip_pos 3, object_pos 3, object_rel_pos 3, finger
    /// qpos 2, object euler 3, object velp − grip velp 3, object velr 3, grip velp 3, finger qvel
    /// 2 (velocities · dt). Reach (10): grip_pos, finger qpos, grip velp, finger qvel.
    pub(super) fn obs(&self) -> Obs {
        let grip_pos = self.data.site_xpos()[self.ids.grip_site];
        let (grip_velp, _) = self.site_vel_dt(self.ids.grip_site, false);
        let (qpos, qvel) = (self.data.qpos(), self.data.qvel());
        let gripper_state = self.ids.gripper_state.map(|(p, _)| qpos[p]);
        let gripper_vel = self.ids.gripper_state.map(|(_, v)| qvel[v] * self.dt);
        let mut o = Vec::with_capacity(self.task.obs_dim);
        o.extend(grip_pos);
        let achieved_goal = match self.ids.object {
            None => {
                o.extend(gripper_state);
                grip_pos.to_vec()
            }
            Some((site, _)) => {
                let object_pos = self.data.site_xpos()[site];
                let object_rot = mat2euler(&self.data.site_xmat()[site]);
                let (velp, object_velr) = self.site_vel_dt(site, true);
                // object_velp -= grip_velp, after both were scaled by dt
                let object_velp: [f64; 3] = std::array::from_fn(|i| velp[i] - grip_velp[i]);
                o.extend(object_pos);
                o.extend(std::array::from_fn::<f64, 3, _>(|i| object_pos[i] - grip_pos[i]));
                o.extend(gripper_state);
                o.extend(object_rot);
                o.extend(object_velp);
                o.extend(object_velr);
                object_pos.to_vec()
            }
        };
        o.extend(grip_velp);
        o.extend(gripper_vel);
        debug_assert_eq!(o.len(), self.task.obs_dim);
        Obs { observation: o, achieved_goal, desired_goal: self.goal.to_vec() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn euler_of_identity_and_of_a_yaw() {
        assert_eq!(mat2euler(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]), [-0.0, -0.0, -0.0]);
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        // Rz(0.3) row-major; gymnasium's convention reports its angle as +0.3 about z.
        let e = mat2euler(&[c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]);
        assert!(e[0].abs() < 1e-15 && e[1].abs() < 1e-15 && (e[2] - 0.3).abs() < 1e-15, "{e:?}");
    }

    #[test]
    fn jacobian_product_is_row_by_row() {
        let jac = [1.0, 2.0, 0.0, 0.0, 1.0, 1.0, 3.0, 0.0, 0.0];
        assert_eq!(jac_times(&jac, &[1.0, 10.0, 100.0]), [21.0, 110.0, 3.0]);
    }
}
