//! Axis-angle ↔ rotation matrix (Rodrigues), numerically stable near zero and near π.

use glam::{Mat3, Vec3};

/// Rotation matrix of an axis-angle vector `θ` (angle = ‖θ‖ radians, right-handed about `θ/‖θ‖`).
///
/// Uses `R = I + a [θ]ₓ + b [θ]ₓ²` with `a = sin‖θ‖/‖θ‖`, `b = (1 − cos‖θ‖)/‖θ‖²`, both from their Taylor
/// series below 1e-4 rad, so tiny angles stay accurate (the reference adds 1e-8 to the norm instead,
/// which differs from this by < 1e-7).
pub fn axis_angle_to_matrix(theta: Vec3) -> Mat3 {
    let t2 = theta.length_squared() as f64;
    let (a, b) = if t2 < 1e-8 {
        (1.0 - t2 / 6.0, 0.5 - t2 / 24.0)
    } else {
        let t = t2.sqrt();
        (t.sin() / t, (1.0 - t.cos()) / t2)
    };
    let k = skew(theta);
    Mat3::IDENTITY + k * a as f32 + (k * k) * b as f32
}

/// Axis-angle vector of a rotation matrix, with angle in `[0, π]`.
///
/// Near zero it uses the first-order inverse of Rodrigues; near π it reads the axis from the symmetric
/// part of `R`, where the usual `(R − Rᵀ)/(2 sin θ)` formula loses all precision.
pub fn matrix_to_axis_angle(r: Mat3) -> Vec3 {
    let m = r.to_cols_array_2d(); // m[col][row]
    let at = |row: usize, col: usize| m[col][row] as f64;
    let cos = ((at(0, 0) + at(1, 1) + at(2, 2) - 1.0) * 0.5).clamp(-1.0, 1.0);
    // vee(R − Rᵀ) = 2 sin θ · axis; atan2 keeps the angle accurate at both ends, where acos is not.
    let v = [
        at(2, 1) - at(1, 2),
        at(0, 2) - at(2, 0),
        at(1, 0) - at(0, 1),
    ];
    let sin = 0.5 * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let angle = sin.atan2(cos);
    if angle < 1e-4 {
        // sinθ/θ ≈ 1 − θ²/6
        let s = 0.5 / (1.0 - angle * angle / 6.0);
        return Vec3::new((v[0] * s) as f32, (v[1] * s) as f32, (v[2] * s) as f32);
    }
    if angle < std::f64::consts::PI - 1e-3 {
        let s = angle / (2.0 * angle.sin());
        return Vec3::new((v[0] * s) as f32, (v[1] * s) as f32, (v[2] * s) as f32);
    }
    // Near π: (R + Rᵀ)/2 − cos θ I = (1 − cos θ) a aᵀ; take the column with the largest diagonal.
    let diag = [at(0, 0), at(1, 1), at(2, 2)];
    let i = (0..3)
        .max_by(|&a, &b| diag[a].total_cmp(&diag[b]))
        .unwrap_or(0);
    let mut axis = [0.0f64; 3];
    for (j, a) in axis.iter_mut().enumerate() {
        let sym = 0.5 * (at(j, i) + at(i, j));
        *a = if j == i { sym - cos } else { sym };
    }
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let mut axis = axis.map(|a| a / n);
    // Choose the sign that agrees with the (small) antisymmetric part.
    if axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2] < 0.0 {
        axis = axis.map(|a| -a);
    }
    Vec3::new(
        (axis[0] * angle) as f32,
        (axis[1] * angle) as f32,
        (axis[2] * angle) as f32,
    )
}

/// Cross-product matrix: `skew(a) b = a × b`.
fn skew(a: Vec3) -> Mat3 {
    Mat3::from_cols(
        Vec3::new(0.0, a.z, -a.y),
        Vec3::new(-a.z, 0.0, a.x),
        Vec3::new(a.y, -a.x, 0.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn max_abs_diff(a: Mat3, b: Mat3) -> f32 {
        (a - b)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()))
    }

    #[test]
    fn quarter_turn_about_z_maps_x_to_y() {
        let r = axis_angle_to_matrix(Vec3::Z * std::f32::consts::FRAC_PI_2);
        assert!((r * Vec3::X - Vec3::Y).length() < 1e-6);
    }

    #[test]
    fn tiny_angles_match_first_order_expansion() {
        for &s in &[1e-12f32, 1e-9, 1e-6, 1e-4] {
            let theta = Vec3::new(0.3, -0.5, 0.8) * s;
            let expected = Mat3::IDENTITY + skew(theta);
            assert!(max_abs_diff(axis_angle_to_matrix(theta), expected) < 1e-7);
            let back = matrix_to_axis_angle(axis_angle_to_matrix(theta));
            assert!(
                (back - theta).length() <= 1e-7 + 1e-3 * theta.length(),
                "{s}: {back} vs {theta}"
            );
        }
    }

    #[test]
    fn round_trip_over_the_whole_angle_range() {
        let axes = [
            Vec3::X,
            Vec3::new(1.0, 2.0, -3.0).normalize(),
            Vec3::new(-0.2, 0.1, 0.97).normalize(),
        ];
        for axis in axes {
            for i in 0..=64 {
                let angle = std::f32::consts::PI * i as f32 / 64.0 * 0.9999;
                let r = axis_angle_to_matrix(axis * angle);
                let back = axis_angle_to_matrix(matrix_to_axis_angle(r));
                assert!(max_abs_diff(r, back) < 2e-5, "angle {angle}");
                assert!((r.determinant() - 1.0).abs() < 1e-5);
                assert!(max_abs_diff(r * r.transpose(), Mat3::IDENTITY) < 1e-5);
            }
        }
    }
}
