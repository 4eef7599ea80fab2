//! The reference's train / novel-pose splits (docs/REFERENCE.md §1.2, §4.1): which cameras train, which
//! frames train and which serve as novel poses. ZJU-MoCap uses the ICCV configs where they exist (313,
//! 315, 377, 386) and the Neural Body / TPAMI ranges for the other sequences.

use serde::{Deserialize, Serialize};

use crate::subject::DatasetKind;

/// Frames `start, start + step, …` (`count` of them), by position in the dataset's frame list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameRange {
    pub start: usize,
    pub count: usize,
    pub step: usize,
}

impl FrameRange {
    /// The frame positions.
    pub fn frames(&self) -> Vec<usize> {
        (0..self.count)
            .map(|i| self.start + i * self.step)
            .collect()
    }

    /// The range cut to the frames that exist.
    fn clamped(self, available: usize) -> Self {
        let count = (0..self.count)
            .take_while(|i| self.start + i * self.step < available)
            .count();
        Self { count, ..self }
    }
}

/// A subject's protocol.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Split {
    pub train_views: Vec<usize>,
    pub test_views: Vec<usize>,
    pub train_frames: FrameRange,
    pub novel_pose_frames: FrameRange,
}

/// The reference split of subject `name` (`CoreView_313`, `S9`, …) with `cameras` cameras and `frames`
/// frames; `None` for subjects the reference does not describe.
pub fn reference_split(
    kind: DatasetKind,
    name: &str,
    cameras: usize,
    frames: usize,
) -> Option<Split> {
    let (train_views, train, novel) = match kind {
        DatasetKind::ZjuMocap => {
            let seq = name.trim_start_matches("CoreView_");
            let (train, novel) = match seq {
                "313" => ((0, 60), (60, 1000)),
                "315" => ((0, 400), (400, 1000)),
                "377" => ((0, 300), (300, 200)),
                "386" => ((0, 300), (300, 346)),
                "390" => ((700, 300), (0, 700)),
                "387" | "392" | "393" | "394" => ((0, 300), (300, 1000)),
                _ => return None,
            };
            let range = |(start, count)| FrameRange {
                start,
                count,
                step: 1,
            };
            (vec![0, 6, 12, 18], range(train), range(novel))
        }
        DatasetKind::H36m => {
            let (train, novel) = match name {
                "S1" => (150, 49),
                "S5" => (250, 127),
                "S6" => (150, 83),
                "S7" => (300, 200),
                "S8" => (250, 87),
                "S9" => (260, 133),
                "S11" => (200, 82),
                _ => return None,
            };
            let step = 5;
            (
                vec![0, 1, 2],
                FrameRange {
                    start: 0,
                    count: train,
                    step,
                },
                FrameRange {
                    start: train * step,
                    count: novel,
                    step,
                },
            )
        }
        DatasetKind::Synthetic | DatasetKind::EasyMocap => return None,
    };
    let train_views: Vec<usize> = train_views.into_iter().filter(|&v| v < cameras).collect();
    Some(Split {
        test_views: (0..cameras).filter(|v| !train_views.contains(v)).collect(),
        train_views,
        train_frames: train.clamped(frames),
        novel_pose_frames: novel.clamped(frames),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_frame_counts_and_view_counts() {
        let s = reference_split(DatasetKind::H36m, "S9", 4, 5000).unwrap();
        assert_eq!((s.train_views, s.test_views), (vec![0, 1, 2], vec![3]));
        assert_eq!(s.train_frames.frames().last(), Some(&1295));
        assert_eq!(s.novel_pose_frames.frames()[0], 1300);
        assert_eq!(s.novel_pose_frames.frames().last(), Some(&1960));
        let z = reference_split(DatasetKind::ZjuMocap, "CoreView_313", 21, 1470).unwrap();
        assert_eq!(z.test_views.len(), 17);
        let z = reference_split(DatasetKind::ZjuMocap, "CoreView_377", 23, 617).unwrap();
        assert_eq!((z.test_views.len(), z.novel_pose_frames.count), (19, 200));
        // Clamped by the sequence length (TPAMI ranges: 392 has 556 frames).
        let z = reference_split(DatasetKind::ZjuMocap, "CoreView_392", 23, 556).unwrap();
        assert_eq!(z.novel_pose_frames.count, 256);
    }
}
