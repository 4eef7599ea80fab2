//! Evaluation reports: per-image metric records (CSV and JSON), a summary JSON, a Markdown table shaped like
//! the paper's tables, the saved images behind every record, and a re-measurement from those images.
//!
//! Layout of an evaluation folder (`<run>/eval/<split>/`):
//! * `metrics.csv`, `metrics.json`: one record per image (split, frame, view, psnr, ssim);
//! * `summary.json`: `{ "psnr": mean, "ssim": mean, "images": n }`; `summary.md`: the Markdown table;
//! * `images/<stem>_{pred,gt}.png` (16-bit) and `images/<stem>_mask.png`: what each record measured;
//! * `side_by_side/<stem>.png`: prediction | ground truth | error heat map (8-bit, for viewing).

use std::io::Write;
use std::path::{Path, PathBuf};

use anerf_core::named::Named;
use anerf_core::{FrameId, ViewId};
use anerf_data::atomic::write_with;
use image::Rgb32FImage;
use serde::{Deserialize, Serialize};

use crate::error::EvalError;
use crate::images::{
    quantised, read_mask, read_rgb, side_by_side, write_mask_png, write_png, PngDepth,
};
use crate::metrics::ImageMetrics;
use crate::pixels::PixelMask;
use crate::silhouette::{SilhouetteMetrics, Silhouettes};

/// The two evaluations of the paper.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EvalSplit {
    /// Training views of training frames: what the model was fitted to, for the gap to the held-out
    /// splits.
    TrainingView,
    /// Test views of training frames.
    NovelView,
    /// Test views of held-out frames (novel poses).
    NovelPose,
}

impl EvalSplit {
    pub const ALL: [EvalSplit; 3] = [
        EvalSplit::TrainingView,
        EvalSplit::NovelView,
        EvalSplit::NovelPose,
    ];
}

impl Named for EvalSplit {
    const KIND: &'static str = "evaluation split";

    fn all() -> &'static [Self] {
        &Self::ALL
    }

    /// The split's name in commands and folders (`<run>/eval/<name>/`).
    fn name(self) -> &'static str {
        match self {
            EvalSplit::TrainingView => "training-view",
            EvalSplit::NovelView => "novel-view",
            EvalSplit::NovelPose => "novel-pose",
        }
    }
}

anerf_core::by_name!(EvalSplit);

/// The metrics of one evaluated image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImageRecord {
    pub split: EvalSplit,
    pub frame: FrameId,
    pub view: ViewId,
    /// dB; +∞ (written as "inf") when prediction and ground truth are identical.
    #[serde(with = "metric_value")]
    pub psnr: f64,
    #[serde(with = "metric_value")]
    pub ssim: f64,
    /// Where the error lies against the true silhouette (when the image had one).
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub silhouette: Option<SilhouetteMetrics>,
}

impl ImageRecord {
    /// File-name stem of the record's saved images.
    pub fn stem(&self) -> String {
        format!(
            "{}_frame{:04}_view{:02}",
            self.split, self.frame.0, self.view.0
        )
    }
}

/// Means over the images of an evaluation (arithmetic means of the per-image numbers, as the reference).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    #[serde(with = "metric_value")]
    pub psnr: f64,
    #[serde(with = "metric_value")]
    pub ssim: f64,
    pub images: usize,
    /// The means of the records' silhouette figures, when every record has them (a side of the band with
    /// no pixel in some image is left out of its mean).
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub silhouette: Option<SilhouetteMetrics>,
}

impl Summary {
    /// The means of `records`, or `None` when there are none.
    pub fn of(records: &[ImageRecord]) -> Option<Self> {
        let n = records.len();
        let silhouettes: Option<Vec<SilhouetteMetrics>> =
            records.iter().map(|r| r.silhouette).collect();
        let mean = |f: fn(&SilhouetteMetrics) -> f64, all: &[SilhouetteMetrics]| {
            let values: Vec<f64> = all.iter().map(f).filter(|v| !v.is_nan()).collect();
            values.iter().sum::<f64>() / values.len() as f64
        };
        (n > 0).then(|| Self {
            psnr: records.iter().map(|r| r.psnr).sum::<f64>() / n as f64,
            ssim: records.iter().map(|r| r.ssim).sum::<f64>() / n as f64,
            images: n,
            silhouette: silhouettes.map(|all| SilhouetteMetrics {
                band_psnr: mean(|s| s.band_psnr, &all),
                outside_band_psnr: mean(|s| s.outside_band_psnr, &all),
                area_ratio: mean(|s| s.area_ratio, &all),
            }),
        })
    }
}

/// A Markdown table like the paper's: one row per subject or split, PSNR to 2 decimals and SSIM to 3, and
/// an `average` row (the mean of the rows, as in the paper) when there is more than one row.
/// When every row has silhouette figures, three more columns give the band's PSNR, the PSNR outside it and
/// the silhouette area ratio ([`SilhouetteMetrics`]).
pub fn markdown_table(first_column: &str, rows: &[(String, Summary)]) -> String {
    let silhouettes = rows.iter().all(|(_, s)| s.silhouette.is_some());
    let mut table = if silhouettes {
        format!(
            "| {first_column} | PSNR | SSIM | band PSNR | outside-band PSNR | area ratio |\n\
             |---|---:|---:|---:|---:|---:|\n"
        )
    } else {
        format!("| {first_column} | PSNR | SSIM |\n|---|---:|---:|\n")
    };
    let line = |label: &str, values: [f64; 5]| {
        let [psnr, ssim, band, outside, area] = values;
        if silhouettes {
            format!("| {label} | {psnr:.2} | {ssim:.3} | {band:.2} | {outside:.2} | {area:.3} |\n")
        } else {
            format!("| {label} | {psnr:.2} | {ssim:.3} |\n")
        }
    };
    let values = |s: &Summary| {
        let sil = s.silhouette.unwrap_or(SilhouetteMetrics {
            band_psnr: f64::NAN,
            outside_band_psnr: f64::NAN,
            area_ratio: f64::NAN,
        });
        [
            s.psnr,
            s.ssim,
            sil.band_psnr,
            sil.outside_band_psnr,
            sil.area_ratio,
        ]
    };
    for (label, summary) in rows {
        table += &line(label, values(summary));
    }
    if rows.len() > 1 {
        let n = rows.len() as f64;
        let all: Vec<[f64; 5]> = rows.iter().map(|(_, s)| values(s)).collect();
        let mean = std::array::from_fn(|i| all.iter().map(|v| v[i]).sum::<f64>() / n);
        table += &line("average", mean);
    }
    table
}

/// Measures and saves the images of one evaluation split, then writes its report.
pub struct EvalRecorder {
    dir: PathBuf,
    split: EvalSplit,
    records: Vec<ImageRecord>,
}

impl EvalRecorder {
    /// Records into `dir` (normally `<run>/eval/<split>`); files appear as images are added.
    pub fn new(dir: impl Into<PathBuf>, split: EvalSplit) -> Self {
        Self {
            dir: dir.into(),
            split,
            records: Vec::new(),
        }
    }

    /// Measures one image with the paper's protocol and saves prediction, ground truth, mask and the
    /// side-by-side composite. As in the reference, `mask` holds the pixels whose ray hits the padded body
    /// box, `gt` already has its background (and everything outside the projected box) set to black, and
    /// `pred` is black outside `mask`; images whose ground truth is all black are kept (the ICCV code does).
    ///
    /// The images are measured as saved (16-bit PNG, steps of 1/65535), so re-measuring the files gives the
    /// same numbers; this moves PSNR by far less than 0.001 dB against the unquantised images.
    /// With `silhouettes` (the true silhouette and the rendered opacity) the record also says where the
    /// error lies ([`SilhouetteMetrics`]).
    pub fn add(
        &mut self,
        frame: FrameId,
        view: ViewId,
        pred: &Rgb32FImage,
        gt: &Rgb32FImage,
        mask: &PixelMask,
        silhouettes: Option<&Silhouettes>,
    ) -> Result<ImageRecord, EvalError> {
        let pred = quantised(pred, PngDepth::Sixteen);
        let gt = quantised(gt, PngDepth::Sixteen);
        let provisional = ImageRecord {
            split: self.split,
            frame,
            view,
            psnr: 0.0,
            ssim: 0.0,
            silhouette: None,
        };
        let stem = provisional.stem();
        let metric_error = |source| EvalError::Metric {
            context: format!("{}, {frame}, {view}", self.split),
            source,
        };
        let metrics = ImageMetrics::compute(&pred, &gt, Some(mask)).map_err(metric_error)?;
        let silhouette = silhouettes
            .map(|s| SilhouetteMetrics::compute(&pred, &gt, mask, s))
            .transpose()
            .map_err(metric_error)?;
        let saved = SavedImages::new(&self.dir, &stem);
        write_png(&saved.pred, &pred, PngDepth::Sixteen)?;
        write_png(&saved.gt, &gt, PngDepth::Sixteen)?;
        write_mask_png(&saved.mask, mask)?;
        write_png(
            &saved.error,
            &crate::heatmap::error_heat_map(&pred, &gt, mask),
            PngDepth::Eight,
        )?;
        let composite = side_by_side(&pred, &gt).expect("sizes were checked by the metrics");
        write_png(
            &self.dir.join("side_by_side").join(format!("{stem}.png")),
            &composite,
            PngDepth::Eight,
        )?;
        let record = ImageRecord {
            psnr: metrics.psnr,
            ssim: metrics.ssim,
            silhouette,
            ..provisional
        };
        self.records.push(record);
        Ok(record)
    }

    /// Writes `metrics.csv`, `metrics.json`, `summary.json`, `summary.md` and the per-view bar charts
    /// `psnr_by_view.svg` and `ssim_by_view.svg`; fails if nothing was recorded.
    pub fn finish(self) -> Result<Summary, EvalError> {
        let summary = Summary::of(&self.records).ok_or_else(|| EvalError::InvalidInput {
            what: "evaluation",
            detail: format!(
                "no image was recorded for {}; expected at least one",
                self.dir.display()
            ),
        })?;
        write_records_csv(&self.dir.join("metrics.csv"), &self.records)?;
        write_json(&self.dir.join("metrics.json"), &self.records)?;
        write_json(&self.dir.join("summary.json"), &summary)?;
        let table = markdown_table("split", &[(self.split.to_string(), summary)]);
        write_with(&self.dir.join("summary.md"), |w| {
            write_text(w, &self.dir.join("summary.md"), &table)
        })?;
        let views = per_view(&self.records);
        for (file, title, unit, metric) in [
            ("psnr_by_view.svg", "PSNR", "dB", 0),
            ("ssim_by_view.svg", "SSIM", "", 1),
        ] {
            let bars: Vec<(String, f64)> = views
                .iter()
                .map(|(view, means)| (format!("view {view}"), means[metric]))
                .collect();
            crate::plots::write_bar_chart(
                &self.dir.join(file),
                &format!(
                    "{} {title} per view ({} images)",
                    self.split,
                    self.records.len()
                ),
                format!("mean {title} {unit}").trim_end(),
                &bars,
            )?;
        }
        Ok(summary)
    }
}

/// Each view's mean PSNR and SSIM over its records, by view.
pub fn per_view(records: &[ImageRecord]) -> Vec<(usize, [f64; 2])> {
    let mut views: std::collections::BTreeMap<usize, (f64, f64, usize)> = Default::default();
    for r in records {
        let e = views.entry(r.view.0).or_default();
        *e = (e.0 + r.psnr, e.1 + r.ssim, e.2 + 1);
    }
    views
        .into_iter()
        .map(|(v, (p, s, n))| (v, [p / n as f64, s / n as f64]))
        .collect()
}

/// Paths of the images saved for one record.
pub struct SavedImages {
    pub pred: PathBuf,
    pub gt: PathBuf,
    pub mask: PathBuf,
    /// The error heat map ([`crate::heatmap`]).
    pub error: PathBuf,
}

impl SavedImages {
    /// The images of the record `stem` ([`ImageRecord::stem`]) in the evaluation folder `dir`.
    pub fn new(dir: &Path, stem: &str) -> Self {
        let images = dir.join("images");
        Self {
            pred: images.join(format!("{stem}_pred.png")),
            gt: images.join(format!("{stem}_gt.png")),
            mask: images.join(format!("{stem}_mask.png")),
            error: images.join(format!("{stem}_error.png")),
        }
    }
}

/// Re-measures every record of the evaluation folder `dir` from its saved images; the result equals the
/// records in `metrics.json` when the report is faithful to the images.
pub fn recompute_from_saved(dir: &Path) -> Result<Vec<ImageRecord>, EvalError> {
    read_records_json(&dir.join("metrics.json"))?
        .into_iter()
        .map(|record| {
            let saved = SavedImages::new(dir, &record.stem());
            let (pred, gt, mask) = (
                read_rgb(&saved.pred)?,
                read_rgb(&saved.gt)?,
                read_mask(&saved.mask)?,
            );
            let metrics = ImageMetrics::compute(&pred, &gt, Some(&mask)).map_err(|source| {
                EvalError::Metric {
                    context: format!("{} against {}", saved.pred.display(), saved.gt.display()),
                    source,
                }
            })?;
            Ok(ImageRecord {
                psnr: metrics.psnr,
                ssim: metrics.ssim,
                ..record
            })
        })
        .collect()
}

/// Reads the records of a `metrics.json`.
pub fn read_records_json(path: &Path) -> Result<Vec<ImageRecord>, EvalError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| EvalError::io(path, "a metrics.json report", e))?;
    serde_json::from_str(&text).map_err(|source| EvalError::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a `summary.json`.
pub fn read_summary_json(path: &Path) -> Result<Summary, EvalError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| EvalError::io(path, "a summary.json report", e))?;
    serde_json::from_str(&text).map_err(|source| EvalError::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes records as CSV with a header; numbers in Rust's shortest round-trip form (`inf` for +∞).
/// The silhouette columns are empty for a record without silhouette figures.
pub fn write_records_csv(path: &Path, records: &[ImageRecord]) -> Result<(), EvalError> {
    let mut text =
        String::from("split,frame,view,psnr,ssim,band_psnr,outside_band_psnr,area_ratio\n");
    for r in records {
        let silhouette = r.silhouette.map_or_else(
            || ",,".to_string(),
            |s| format!("{},{},{}", s.band_psnr, s.outside_band_psnr, s.area_ratio),
        );
        text += &format!(
            "{},{},{},{},{},{silhouette}\n",
            r.split, r.frame.0, r.view.0, r.psnr, r.ssim
        );
    }
    write_with(path, |w| write_text(w, path, &text))
}

/// Writes `value` as pretty JSON atomically.
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<(), EvalError> {
    let text = serde_json::to_string_pretty(value).map_err(|source| EvalError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    write_with(path, |w| write_text(w, path, &(text + "\n")))
}

fn write_text(w: &mut dyn Write, path: &Path, text: &str) -> Result<(), EvalError> {
    w.write_all(text.as_bytes())
        .map_err(|source| EvalError::Io {
            path: path.to_path_buf(),
            source,
        })
}

/// Metric values in JSON: finite numbers as numbers, ±∞ and NaN (which JSON cannot hold) as "inf",
/// "-inf" and "nan".
pub(crate) mod metric_value {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_str(&v.to_string().to_lowercase())
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Value {
            Number(f64),
            Text(String),
        }
        match Value::deserialize(d)? {
            Value::Number(v) => Ok(v),
            Value::Text(t) => match t.as_str() {
                "inf" => Ok(f64::INFINITY),
                "-inf" => Ok(f64::NEG_INFINITY),
                "nan" => Ok(f64::NAN),
                other => Err(serde::de::Error::custom(format!(
                    "expected a number, \"inf\", \"-inf\" or \"nan\", got {other:?}"
                ))),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(psnr: f64, ssim: f64) -> ImageRecord {
        ImageRecord {
            split: EvalSplit::NovelPose,
            frame: FrameId(3),
            view: ViewId(7),
            psnr,
            ssim,
            silhouette: None,
        }
    }

    #[test]
    fn summary_is_the_arithmetic_mean() {
        let summary =
            Summary::of(&[record(20.0, 0.8), record(30.0, 0.9), record(25.0, 1.0)]).unwrap();
        assert_eq!((summary.psnr, summary.images), (25.0, 3));
        assert!((summary.ssim - 0.9).abs() < 1e-15);
        assert!(Summary::of(&[]).is_none());
    }

    #[test]
    fn markdown_table_has_the_papers_shape() {
        let rows = [
            (
                "S1".to_string(),
                Summary {
                    psnr: 22.054,
                    ssim: 0.8884,
                    images: 9,
                    silhouette: None,
                },
            ),
            (
                "S5".to_string(),
                Summary {
                    psnr: 23.27,
                    ssim: 0.892,
                    images: 5,
                    silhouette: None,
                },
            ),
        ];
        let expected = "| subject | PSNR | SSIM |\n|---|---:|---:|\n| S1 | 22.05 | 0.888 |\n| S5 | 23.27 | 0.892 |\n\
                        | average | 22.66 | 0.890 |\n";
        assert_eq!(markdown_table("subject", &rows), expected);
        assert_eq!(
            markdown_table("split", &rows[..1]).lines().count(),
            3,
            "no average row for one row"
        );
    }

    #[test]
    fn records_survive_json_including_infinite_psnr() {
        let records = vec![record(f64::INFINITY, 1.0), record(23.5, 0.875)];
        let text = serde_json::to_string(&records).unwrap();
        assert!(
            text.contains("\"psnr\":\"inf\"") && text.contains("\"split\":\"novel-pose\""),
            "{text}"
        );
        assert!(
            text.contains("\"frame\":3") && text.contains("\"view\":7"),
            "{text}"
        );
        let back: Vec<ImageRecord> = serde_json::from_str(&text).unwrap();
        assert_eq!(back, records);
        let single = serde_json::to_string(&records[0]).unwrap();
        assert!(serde_json::from_str::<ImageRecord>(&single).is_ok());
        assert!(
            serde_json::from_str::<ImageRecord>(&single.replace("\"inf\"", "\"lots\"")).is_err()
        );
    }

    #[test]
    fn split_names_parse_back() {
        for split in EvalSplit::ALL {
            assert_eq!(split.name().parse::<EvalSplit>(), Ok(split));
        }
        assert!("novel_view".parse::<EvalSplit>().is_err());
    }
}
