//! The checks of a resolved config that serde cannot make.

use super::frames::MAX_RANGE_FRAMES;
use super::{ConfigError, ExperimentConfig, RangeSet};

/// Checks values serde cannot: ranges, sizes and positivity. Errors name the key.
pub fn validate(c: &ExperimentConfig) -> Result<(), ConfigError> {
    let bad = |key: &str, why: String| Err(ConfigError::Invalid(format!("{key}: {why}")));
    c.model.validate().map_err(ConfigError::Invalid)?;
    let d = &c.dataset;
    if d.train_views.is_empty() {
        return bad(
            "dataset.train_views",
            "empty (expected at least one camera index)".into(),
        );
    }
    if d.frame_interval == 0 {
        return bad(
            "dataset.frame_interval",
            "0 (expected a positive integer)".into(),
        );
    }
    for (name, split) in [
        ("dataset.iccv", Some(&d.iccv)),
        ("dataset.tpami", d.tpami.as_ref()),
    ] {
        if let Some(s) = split {
            for (key, range) in [
                ("train_frames", &s.train_frames),
                ("novel_pose_frames", &s.novel_pose_frames),
            ] {
                if range.len() > MAX_RANGE_FRAMES {
                    return bad(
                        &format!("{name}.{key}"),
                        format!(
                            "{range} holds {} frames; a range may hold at most {MAX_RANGE_FRAMES} (frames \
                             past the dataset's last are cut when it is loaded)",
                            range.len()
                        ),
                    );
                }
            }
            if s.train_frames.is_empty() {
                return bad(
                    &format!("{name}.train_frames"),
                    format!("{} holds no frame", s.train_frames),
                );
            }
            let train = s.train_frames.frames();
            if let Some(f) = s
                .novel_pose_frames
                .frames()
                .into_iter()
                .find(|f| train.binary_search(f).is_ok())
            {
                return bad(
                    &format!("{name}.novel_pose_frames"),
                    format!(
                        "{} shares frame {f} with {name}.train_frames = {} (novel poses must be frames the \
                         model was not trained on)",
                        s.novel_pose_frames, s.train_frames
                    ),
                );
            }
        }
    }
    if d.ranges == RangeSet::Tpami && d.tpami.is_none() {
        return bad(
            "dataset.ranges",
            "\"tpami\" but the config has no [dataset.tpami] section".into(),
        );
    }
    for (name, s) in [("train", &c.train), ("animate", &c.animate)] {
        if s.iterations == 0 {
            return bad(
                &format!("{name}.iterations"),
                "0 (expected at least one step)".into(),
            );
        }
        if s.batch == 0 {
            return bad(
                &format!("{name}.batch"),
                "0 (expected a positive integer)".into(),
            );
        }
        for (key, rate) in [("lr", s.lr), ("lr_final", s.lr_final)] {
            if !(rate.is_finite() && rate > 0.0) {
                return bad(
                    &format!("{name}.{key}"),
                    format!("{rate} (expected a positive, finite rate)"),
                );
            }
        }
        if s.grad_clip.is_nan() || s.grad_clip < 0.0 {
            return bad(
                &format!("{name}.grad_clip"),
                format!("{} (expected ≥ 0; 0 disables)", s.grad_clip),
            );
        }
        for (key, weight) in [
            ("mask_weight", s.mask_weight),
            ("residual_weight", s.residual_weight),
        ] {
            if !(weight.is_finite() && weight >= 0.0) {
                return bad(
                    &format!("{name}.{key}"),
                    format!("{weight} (expected ≥ 0; 0 disables)"),
                );
            }
        }
        if !(s.edge_scale.is_finite() && s.edge_scale > 0.0) {
            return bad(
                &format!("{name}.edge_scale"),
                format!("{} (expected a positive, finite error scale)", s.edge_scale),
            );
        }
        if !(s.plateau_tolerance.is_finite() && (0.0..1.0).contains(&s.plateau_tolerance)) {
            return bad(
                &format!("{name}.plateau_tolerance"),
                format!("{} (expected 0 ≤ tolerance < 1)", s.plateau_tolerance),
            );
        }
        if s.log_every == 0 {
            return bad(
                &format!("{name}.log_every"),
                "0 (expected a positive integer)".into(),
            );
        }
    }
    if c.eval.frame_interval == 0 || c.eval.chunk == 0 {
        return bad("eval", "frame_interval and chunk must be positive".into());
    }
    if !(0.0..1.0).contains(&c.eval.termination) {
        return bad(
            "eval.termination",
            format!("{} (expected 0 ≤ termination < 1)", c.eval.termination),
        );
    }
    if let Err(why) = anerf_data::paths::check_component(&c.name) {
        return bad(
            "name",
            format!(
                "'{}' {why} (expected one folder name: the run goes to runs/<name>)",
                c.name
            ),
        );
    }
    Ok(())
}
