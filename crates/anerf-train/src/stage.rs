//! The two optimisation stages of a run.

use serde::{Deserialize, Serialize};

/// Stage 1 (`anerf train`) fits the canonical radiance field and the training frames' blend-weight fields;
/// stage 2 (`anerf animate`) fits blend-weight fields for the novel poses against the frozen stage-1 model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(try_from = "u8", into = "u8")]
pub enum Stage {
    Train = 1,
    Animate = 2,
}

impl Stage {
    /// Both stages, in the order a run trains them.
    pub const ALL: [Stage; 2] = [Stage::Train, Stage::Animate];

    /// The stage's section of a config (`train`, `animate`).
    pub fn section(self) -> &'static str {
        match self {
            Stage::Train => "train",
            Stage::Animate => "animate",
        }
    }

    /// 1 or 2, as written in checkpoint names, `metrics.jsonl` and messages.
    pub fn number(self) -> u8 {
        self as u8
    }
}

impl From<Stage> for u8 {
    fn from(stage: Stage) -> u8 {
        stage.number()
    }
}

impl TryFrom<u8> for Stage {
    type Error = anerf_core::InvalidValue;

    fn try_from(n: u8) -> Result<Self, Self::Error> {
        match n {
            1 => Ok(Stage::Train),
            2 => Ok(Stage::Animate),
            _ => Err(anerf_core::InvalidValue::new("stage", n, "1 or 2")),
        }
    }
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "stage {}", self.number())
    }
}
