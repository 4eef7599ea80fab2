//! The checks of a resolved config that serde cannot make: one `validate` per section, each error an
//! [`InvalidValue`] naming the key, the value and what the key accepts.

use anerf_core::InvalidValue;

use super::frames::MAX_RANGE_FRAMES;
use super::{
    ConfigError, DatasetConfig, EvalConfig, ExperimentConfig, FrameSplit, RangeSet, StageConfig,
};

/// Checks every section (ranges, sizes, positivity) and the run's name.
pub fn validate(c: &ExperimentConfig) -> Result<(), ConfigError> {
    c.model.validate()?;
    c.dataset.validate()?;
    c.train.validate("train")?;
    c.animate.validate("animate")?;
    c.eval.validate()?;
    if let Err(why) = anerf_data::paths::check_component(&c.name) {
        return Err(InvalidValue::new(
            "name",
            format!("'{}' ({why})", c.name),
            "one folder name: the run goes to runs/<name>",
        )
        .into());
    }
    Ok(())
}

impl DatasetConfig {
    pub fn validate(&self) -> Result<(), InvalidValue> {
        if self.train_views.is_empty() {
            return Err(InvalidValue::new(
                "dataset.train_views",
                "[]",
                "at least one camera index",
            ));
        }
        if self.frame_interval == 0 {
            return Err(InvalidValue::new(
                "dataset.frame_interval",
                0,
                "a positive integer",
            ));
        }
        self.iccv.validate("dataset.iccv")?;
        if let Some(tpami) = &self.tpami {
            tpami.validate("dataset.tpami")?;
        }
        if self.ranges == RangeSet::Tpami && self.tpami.is_none() {
            return Err(InvalidValue::new(
                "dataset.ranges",
                "\"tpami\"",
                "\"iccv\", or a [dataset.tpami] section",
            ));
        }
        Ok(())
    }
}

impl FrameSplit {
    /// `name`: the split's section, e.g. `dataset.iccv`.
    fn validate(&self, name: &str) -> Result<(), InvalidValue> {
        for (key, range) in [
            ("train_frames", &self.train_frames),
            ("novel_pose_frames", &self.novel_pose_frames),
        ] {
            if range.len() > MAX_RANGE_FRAMES {
                return Err(InvalidValue::new(
                    format!("{name}.{key}"),
                    format!("{range} ({} frames)", range.len()),
                    format!(
                        "a range of at most {MAX_RANGE_FRAMES} frames (frames past the dataset's last are \
                         cut when it is loaded)"
                    ),
                ));
            }
        }
        if self.train_frames.is_empty() {
            return Err(InvalidValue::new(
                format!("{name}.train_frames"),
                self.train_frames,
                "a range holding at least one frame",
            ));
        }
        let train = self.train_frames.frames();
        if let Some(f) = self
            .novel_pose_frames
            .frames()
            .into_iter()
            .find(|f| train.binary_search(f).is_ok())
        {
            return Err(InvalidValue::new(
                format!("{name}.novel_pose_frames"),
                self.novel_pose_frames,
                format!(
                    "frames the model was not trained on (frame {f} is in {name}.train_frames = {})",
                    self.train_frames
                ),
            ));
        }
        Ok(())
    }
}

impl StageConfig {
    /// `section`: `train` or `animate`.
    pub fn validate(&self, section: &str) -> Result<(), InvalidValue> {
        let bad = |key: &str, value: &dyn std::fmt::Display, expected: &str| {
            Err(InvalidValue::new(
                format!("{section}.{key}"),
                value,
                expected,
            ))
        };
        if self.iterations == 0 {
            return bad("iterations", &0, "at least one step");
        }
        if self.batch == 0 {
            return bad("batch", &0, "a positive integer");
        }
        if self.views_per_step == 0 || self.views_per_step > self.batch {
            return bad(
                "views_per_step",
                &self.views_per_step,
                "1 up to the batch (each view gets a ray at least)",
            );
        }
        if self.frames_per_step == 0
            || self.frames_per_step.saturating_mul(self.views_per_step) > self.batch
        {
            return bad(
                "frames_per_step",
                &self.frames_per_step,
                "1 up to the batch over views_per_step (each image gets a ray at least)",
            );
        }
        if !(0.0..=1.0).contains(&self.detail_fraction) {
            return bad(
                "detail_fraction",
                &self.detail_fraction,
                "a share of the rays, from 0 to 1",
            );
        }
        for (key, rate) in [("lr", self.lr), ("lr_final", self.lr_final)] {
            if !(rate.is_finite() && rate > 0.0) {
                return bad(key, &rate, "a positive, finite rate");
            }
        }
        if self.grad_clip.is_nan() || self.grad_clip < 0.0 {
            return bad("grad_clip", &self.grad_clip, "≥ 0 (0 disables)");
        }
        for (key, weight) in [
            ("mask_weight", self.mask_weight),
            ("hard_surface_weight", self.hard_surface_weight),
            ("residual_weight", self.residual_weight),
        ] {
            if !(weight.is_finite() && weight >= 0.0) {
                return bad(key, &weight, "≥ 0 (0 disables)");
            }
        }
        if !(self.edge_scale.is_finite() && self.edge_scale > 0.0) {
            return bad(
                "edge_scale",
                &self.edge_scale,
                "a positive, finite error scale",
            );
        }
        if !(self.plateau_tolerance.is_finite() && (0.0..1.0).contains(&self.plateau_tolerance)) {
            return bad(
                "plateau_tolerance",
                &self.plateau_tolerance,
                "0 ≤ tolerance < 1",
            );
        }
        if self.log_every == 0 {
            return bad("log_every", &0, "a positive integer");
        }
        Ok(())
    }
}

impl EvalConfig {
    pub fn validate(&self) -> Result<(), InvalidValue> {
        for (key, value) in [
            ("eval.frame_interval", self.frame_interval),
            ("eval.chunk", self.chunk),
        ] {
            if value == 0 {
                return Err(InvalidValue::new(key, 0, "a positive integer"));
            }
        }
        if !(0.0..1.0).contains(&self.termination) {
            return Err(InvalidValue::new(
                "eval.termination",
                self.termination,
                "0 ≤ termination < 1",
            ));
        }
        Ok(())
    }
}
