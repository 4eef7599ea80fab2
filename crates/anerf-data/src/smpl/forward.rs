//! The SMPL forward model (Loper et al. 2015), in f64: shape blend shapes, joint regression, pose
//! correctives, linear blend skinning, then the global `R(Rh) x + Th` of EasyMocap's fits.

use glam::{DMat3, DMat4, DVec3};

use super::SmplModel;

/// One body's parameters as EasyMocap writes them: `betas` (at most the model's count; missing ones are 0),
/// axis-angle `poses` of the first `poses.len() / 3` joints (the rest stay unrotated: SMPL-H and SMPL-X
/// fits drive the body joints), and the global rotation `rh` (axis-angle) and translation `th` (metres).
#[derive(Debug, Clone, PartialEq)]
pub struct SmplParams {
    pub betas: Vec<f64>,
    pub poses: Vec<f64>,
    pub rh: DVec3,
    pub th: DVec3,
}

/// A posed body in world space (metres).
#[derive(Debug, Clone, PartialEq)]
pub struct PosedSmpl {
    pub vertices: Vec<DVec3>,
    pub joints: Vec<DVec3>,
}

/// Rotation matrix of an axis-angle vector (radians); exact to first order below 1e-12 rad.
pub(crate) fn rodrigues(r: DVec3) -> DMat3 {
    let angle = r.length();
    if angle < 1e-12 {
        // I + [r]×: the limit of the formula, without dividing by the angle.
        return DMat3::from_cols(
            DVec3::new(1.0, r.z, -r.y),
            DVec3::new(-r.z, 1.0, r.x),
            DVec3::new(r.y, -r.x, 1.0),
        );
    }
    DMat3::from_axis_angle(r / angle, angle)
}

impl SmplModel {
    /// Shaped template vertices `v_template + shapedirs · betas` (metres, model frame); panics when
    /// `betas` has more coefficients than the model (the loaders check this with the file named).
    pub fn shaped(&self, betas: &[f64]) -> Vec<DVec3> {
        assert!(
            betas.len() <= self.num_betas,
            "{} betas for a model of {}",
            betas.len(),
            self.num_betas
        );
        let b = self.num_betas;
        self.v_template
            .iter()
            .enumerate()
            .map(|(v, &t)| {
                let offset = |c: usize| -> f64 {
                    let row = &self.shapedirs[(v * 3 + c) * b..(v * 3 + c) * b + betas.len()];
                    row.iter().zip(betas).map(|(d, x)| d * x).sum()
                };
                t + DVec3::new(offset(0), offset(1), offset(2))
            })
            .collect()
    }

    /// Joints regressed from (shaped) vertices: `J = J_regressor · vertices`.
    pub fn regress_joints(&self, vertices: &[DVec3]) -> Vec<DVec3> {
        let v = self.num_vertices();
        self.j_regressor
            .chunks_exact(v)
            .map(|row| {
                row.iter()
                    .zip(vertices)
                    .filter(|(w, _)| **w != 0.0)
                    .map(|(w, p)| *p * *w)
                    .sum()
            })
            .collect()
    }

    /// The posed body in world space; `correctives` adds the pose blend shapes (SMPL's `posedirs`).
    /// Panics when `params` has more betas or joints than the model.
    pub fn pose(&self, params: &SmplParams, correctives: bool) -> PosedSmpl {
        let k = self.num_joints();
        assert!(
            params.poses.len().is_multiple_of(3) && params.poses.len() <= 3 * k,
            "{} pose values for a model of {k} joints",
            params.poses.len()
        );
        let rotations: Vec<DMat3> = (0..k)
            .map(|j| match params.poses.get(3 * j..3 * j + 3) {
                Some(r) => rodrigues(DVec3::new(r[0], r[1], r[2])),
                None => DMat3::IDENTITY,
            })
            .collect();
        let shaped = self.shaped(&params.betas);
        let joints = self.regress_joints(&shaped);
        let posed_rest = if correctives {
            self.with_correctives(&shaped, &rotations)
        } else {
            shaped
        };
        // Chain each joint's rotation about its rest position: G_k = G_parent · [R_k | J_k − J_parent].
        let mut global: Vec<DMat4> = Vec::with_capacity(k);
        for j in 0..k {
            let offset = match self.parents[j] {
                Some(p) => joints[j] - joints[p],
                None => joints[j],
            };
            let local = DMat4::from_mat3_translation(rotations[j], offset);
            global.push(match self.parents[j] {
                Some(p) => global[p] * local,
                None => local,
            });
        }
        let world = DMat4::from_mat3_translation(rodrigues(params.rh), params.th);
        // A_k maps a rest-pose point to its posed place: G_k with the rest joint position taken out.
        let bones: Vec<DMat4> = global
            .iter()
            .zip(&joints)
            .map(|(g, &j)| *g * DMat4::from_translation(-j))
            .collect();
        let vertices = posed_rest
            .iter()
            .enumerate()
            .map(|(v, &p)| {
                let blended = self
                    .vertex_weights(v)
                    .iter()
                    .zip(&bones)
                    .fold(DMat4::ZERO, |acc, (&w, a)| acc + *a * w);
                world.transform_point3(blended.transform_point3(p))
            })
            .collect();
        let joints = global
            .iter()
            .map(|g| world.transform_point3(g.w_axis.truncate()))
            .collect();
        PosedSmpl { vertices, joints }
    }

    /// `shaped + posedirs · vec(R_k − I for k = 1..K)`: the pose correctives.
    fn with_correctives(&self, shaped: &[DVec3], rotations: &[DMat3]) -> Vec<DVec3> {
        let feature: Vec<f64> = rotations[1..]
            .iter()
            .flat_map(|r| {
                let d = *r - DMat3::IDENTITY;
                // Row-major entries of R − I, as the files' posedirs are laid out.
                let t = d.transpose().to_cols_array();
                t.into_iter()
            })
            .collect();
        let p = feature.len();
        shaped
            .iter()
            .enumerate()
            .map(|(v, &s)| {
                let offset = |c: usize| -> f64 {
                    let row = &self.posedirs[(v * 3 + c) * p..(v * 3 + c + 1) * p];
                    row.iter().zip(&feature).map(|(d, x)| d * x).sum()
                };
                s + DVec3::new(offset(0), offset(1), offset(2))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rodrigues_is_a_rotation_by_the_vectors_length_about_it_and_continuous_at_zero() {
        let r = DVec3::new(0.3, -0.4, 1.2);
        let m = rodrigues(r);
        assert!((m * r - r).length() < 1e-12, "the axis is fixed");
        assert!((m.determinant() - 1.0).abs() < 1e-12);
        let x = r.normalize().any_orthonormal_vector();
        assert!(((m * x).dot(x) - r.length().cos()).abs() < 1e-12);
        let tiny = DVec3::new(1e-13, -2e-13, 3e-13);
        let a = rodrigues(tiny);
        let b = DMat3::from_axis_angle(tiny.normalize(), tiny.length());
        assert!((a - b).to_cols_array().iter().all(|d| d.abs() < 1e-20));
    }
}
