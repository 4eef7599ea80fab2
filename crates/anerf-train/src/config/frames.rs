//! Frame ranges `start:end[:step]` of configs and command lines.

use anerf_core::InvalidValue;
use serde::{Deserialize, Serialize};

/// A half-open range of frame indices `start..end` stepping by `step`, written `"start:end"` or
/// `"start:end:step"` in configs and on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameRange {
    pub start: usize,
    pub end: usize,
    pub step: usize,
}

/// Most frames one range may hold (about nine hours at 30 frames per second, more than any capture has):
/// config validation refuses longer ranges before any list of them is made.
pub const MAX_RANGE_FRAMES: usize = 1_000_000;

impl FrameRange {
    /// The frame indices (callers check [`FrameRange::len`] against [`MAX_RANGE_FRAMES`] or cut the range
    /// to a dataset with [`FrameRange::within`] first).
    pub fn frames(&self) -> Vec<usize> {
        (self.start..self.end).step_by(self.step.max(1)).collect()
    }

    /// Number of frames, computed without listing them.
    pub fn len(&self) -> usize {
        self.end
            .saturating_sub(self.start)
            .div_ceil(self.step.max(1))
    }

    /// The range cut to the `available` frames of a dataset.
    pub fn within(&self, available: usize) -> FrameRange {
        FrameRange {
            end: self.end.min(available).max(self.start.min(available)),
            start: self.start.min(available),
            ..*self
        }
    }

    /// True when the range holds no frame.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl std::str::FromStr for FrameRange {
    type Err = InvalidValue;

    fn from_str(s: &str) -> Result<Self, InvalidValue> {
        let bad = |expected: &str| InvalidValue::new("frame range", format!("'{s}'"), expected);
        const FORM: &str = "start:end[:step]";
        let parts: Vec<&str> = s.split(':').collect();
        let num = |p: &str| p.trim().parse::<usize>().map_err(|_| bad(FORM));
        let range = match parts.as_slice() {
            [a, b] => FrameRange {
                start: num(a)?,
                end: num(b)?,
                step: 1,
            },
            [a, b, c] => FrameRange {
                start: num(a)?,
                end: num(b)?,
                step: num(c)?,
            },
            _ => return Err(bad(FORM)),
        };
        if range.end < range.start || range.step == 0 {
            return Err(bad("start ≤ end and a positive step"));
        }
        Ok(range)
    }
}

impl std::fmt::Display for FrameRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.step == 1 {
            write!(f, "{}:{}", self.start, self.end)
        } else {
            write!(f, "{}:{}:{}", self.start, self.end, self.step)
        }
    }
}

impl Serialize for FrameRange {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for FrameRange {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}
