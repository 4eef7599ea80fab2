//! `<run>/baked/`: a baked avatar as NumPy arrays, one row per Gaussian — `means.npy` (`[N, 3]`, canonical
//! space, metres), `log_scales.npy` (`[N, 3]`, log metres), `rotations.npy` (`[N, 4]`, quaternions
//! `w, x, y, z`), `opacity_logits.npy` (`[N, 1]`), `colours.npy` (`[N, 3·(d+1)²]`, spherical harmonics,
//! coefficient-major), `skin_joints.npy` (`[N, 4]` int32) and `skin_weights.npy` (`[N, 4]`, rows summing
//! to 1) — with `avatar.json` ([`AvatarInfo`]) and a `manifest.json` of the files. Written into a temporary
//! folder beside it and renamed into place; read back only when the manifest checks.

use std::path::Path;

use anerf_core::gaussians::sh;
use anerf_core::gaussians::{GaussianCloud, HostCloud, Splats, MAX_GAUSSIANS};
use anerf_core::tensor::{from_rows, to_host};
use anerf_data::atomic::{replace_dir, temp_dir_beside, write_bytes};
use anerf_data::formats::ndarray::{ArrayData, NdArray};
use anerf_data::formats::{read_npy, write_npy};
use anerf_train::manifest::Manifest;
use anyhow::{bail, Context, Result};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

/// Blend weights kept per Gaussian (as glTF keeps per vertex).
pub use anerf_core::gaussians::host::SKIN_SLOTS;

const INFO: &str = "avatar.json";
const ARRAYS: [&str; 7] = [
    "means.npy",
    "log_scales.npy",
    "rotations.npy",
    "opacity_logits.npy",
    "colours.npy",
    "skin_joints.npy",
    "skin_weights.npy",
];

/// `avatar.json`: what the arrays hold and how they were made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AvatarInfo {
    pub gaussians: usize,
    /// Spherical-harmonic degree of the colours (0 or 1).
    pub sh_degree: usize,
    /// Joints of the skeleton the skin indexes.
    pub joints: usize,
    /// The checkpoint folder the avatar was baked from.
    pub source: String,
    /// Fine-tuning steps and their wall time.
    pub steps: usize,
    pub seconds: f64,
    /// PSNR (dB) of the last steps' training crops, colour on black.
    pub training_psnr: f64,
}

/// A baked avatar on the host.
#[derive(Debug, Clone, PartialEq)]
pub struct BakedAvatar {
    pub info: AvatarInfo,
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 3]>,
    pub rotations: Vec<[f32; 4]>,
    pub opacity_logits: Vec<f32>,
    /// `N × 3·(d+1)²`, row-major.
    pub colours: Vec<f32>,
    pub skin_joints: Vec<[u16; SKIN_SLOTS]>,
    pub skin_weights: Vec<[f32; SKIN_SLOTS]>,
}

impl BakedAvatar {
    /// The Gaussians' arrays, in canonical space.
    pub fn splats(&self) -> Splats<'_> {
        Splats {
            means: &self.means,
            log_scales: &self.log_scales,
            rotations: &self.rotations,
            opacity_logits: &self.opacity_logits,
            colours: &self.colours,
        }
    }

    /// The arrays as the host projection reads them.
    pub fn host_cloud(&self) -> HostCloud<'_> {
        HostCloud {
            splats: self.splats(),
            skin_joints: &self.skin_joints,
            skin_weights: &self.skin_weights,
        }
    }

    /// The learnable cloud on `device`.
    pub fn cloud(&self, device: &Device) -> GaussianCloud {
        let n = self.means.len();
        let flat = |rows: &[f32], width: usize| from_rows(rows, n, width, device);
        GaussianCloud::new(
            flat(self.means.as_flattened(), 3),
            flat(self.log_scales.as_flattened(), 3),
            flat(self.rotations.as_flattened(), 4),
            flat(&self.opacity_logits, 1),
            flat(&self.colours, 3 * sh::coefficients(self.info.sh_degree)),
        )
    }

    /// The skin as dense blend weights `[N, K]` on `device`.
    pub fn skin(&self, device: &Device) -> Tensor<2> {
        let k = self.info.joints;
        let mut dense = vec![0.0f32; self.means.len() * k];
        for (i, (joints, weights)) in self.skin_joints.iter().zip(&self.skin_weights).enumerate() {
            for (&j, &w) in joints.iter().zip(weights) {
                dense[i * k + j as usize] += w;
            }
        }
        from_rows(&dense, self.means.len(), k, device)
    }

    /// The avatar with the cloud's current values (same skin and info).
    pub fn with_cloud(&self, cloud: &GaussianCloud) -> Self {
        let rows3 = |t: Tensor<2>| -> Vec<[f32; 3]> {
            to_host(t)
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect()
        };
        Self {
            means: rows3(cloud.means.val()),
            log_scales: rows3(cloud.log_scales.val()),
            rotations: to_host(cloud.rotations.val())
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            opacity_logits: to_host(cloud.opacity_logits.val()),
            colours: to_host(cloud.colours.val()),
            ..self.clone()
        }
    }

    /// Writes the avatar to `dir` (replacing what is there only once the new folder is complete).
    pub fn save(&self, dir: &Path) -> Result<()> {
        let staging = temp_dir_beside(dir)?;
        let n = self.means.len();
        let floats = |rows: &[f32], width: usize| {
            NdArray::new(vec![n, width], ArrayData::F32(rows.to_vec())).expect("rows of the width")
        };
        let joints: Vec<i32> = self
            .skin_joints
            .as_flattened()
            .iter()
            .map(|&j| j as i32)
            .collect();
        let arrays = [
            floats(self.means.as_flattened(), 3),
            floats(self.log_scales.as_flattened(), 3),
            floats(self.rotations.as_flattened(), 4),
            floats(&self.opacity_logits, 1),
            floats(&self.colours, 3 * sh::coefficients(self.info.sh_degree)),
            NdArray::new(vec![n, SKIN_SLOTS], ArrayData::I32(joints)).expect("four per row"),
            floats(self.skin_weights.as_flattened(), SKIN_SLOTS),
        ];
        for (name, array) in ARRAYS.iter().zip(&arrays) {
            write_npy(&staging.path().join(name), array)?;
        }
        write_bytes(
            &staging.path().join(INFO),
            serde_json::to_string_pretty(&self.info)?.as_bytes(),
        )?;
        let mut names = ARRAYS.to_vec();
        names.push(INFO);
        Manifest::write(staging.path(), &names)?;
        replace_dir(staging, dir)?;
        Ok(())
    }

    /// Reads the avatar in `dir`, checking its manifest, its size (at most [`MAX_GAUSSIANS`], before any
    /// array is read), shapes and values (finite, skin joints below `info.joints`, weights non-negative).
    pub fn load(dir: &Path) -> Result<Self> {
        let manifest = Manifest::read(dir)?.with_context(|| {
            format!(
                "{} holds no finished avatar (no manifest.json); run `anerf bake` again",
                dir.display()
            )
        })?;
        manifest.check(dir)?;
        let info_path = dir.join(INFO);
        let info: AvatarInfo = serde_json::from_str(
            &std::fs::read_to_string(&info_path)
                .with_context(|| format!("reading {}", info_path.display()))?,
        )
        .with_context(|| format!("{} is not an avatar description", info_path.display()))?;
        if sh::degree_of(3 * sh::coefficients(info.sh_degree)) != Some(info.sh_degree) {
            bail!(
                "{}: sh_degree {} (expected 0 or 1)",
                info_path.display(),
                info.sh_degree
            );
        }
        let n = info.gaussians;
        if n > MAX_GAUSSIANS {
            bail!(
                "{}: {n} Gaussians (at most {MAX_GAUSSIANS} are read)",
                info_path.display()
            );
        }
        let read = |name: &str, width: usize| -> Result<NdArray> {
            let path = dir.join(name);
            let array = read_npy(&path)?;
            if array.shape() != [n, width] {
                bail!(
                    "{}: shape {:?}, expected [{n}, {width}] ({n} Gaussians in {INFO})",
                    path.display(),
                    array.shape()
                );
            }
            Ok(array)
        };
        let floats = |name: &str, width: usize| -> Result<Vec<f32>> {
            let values = read(name, width)?.to_f32();
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                bail!("{}: value {i} is {}", dir.join(name).display(), values[i]);
            }
            Ok(values)
        };
        let rows = |v: Vec<f32>, width: usize| -> Vec<Vec<f32>> {
            v.chunks_exact(width).map(<[f32]>::to_vec).collect()
        };
        let joints = read("skin_joints.npy", SKIN_SLOTS)?
            .to_i64()
            .context("skin_joints.npy: expected integers")?;
        if let Some(&j) = joints.iter().find(|&&j| j < 0 || j >= info.joints as i64) {
            bail!(
                "{}: joint {j} (expected 0 to {} for {} joints)",
                dir.join("skin_joints.npy").display(),
                info.joints.saturating_sub(1),
                info.joints
            );
        }
        let weights = floats("skin_weights.npy", SKIN_SLOTS)?;
        if weights.iter().any(|&w| w < 0.0) {
            bail!(
                "{}: a negative weight",
                dir.join("skin_weights.npy").display()
            );
        }
        let fixed =
            |v: Vec<Vec<f32>>| -> Vec<[f32; 3]> { v.iter().map(|r| [r[0], r[1], r[2]]).collect() };
        Ok(Self {
            means: fixed(rows(floats("means.npy", 3)?, 3)),
            log_scales: fixed(rows(floats("log_scales.npy", 3)?, 3)),
            rotations: floats("rotations.npy", 4)?
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            opacity_logits: floats("opacity_logits.npy", 1)?,
            colours: floats("colours.npy", 3 * sh::coefficients(info.sh_degree))?,
            skin_joints: joints
                .chunks_exact(SKIN_SLOTS)
                .map(|c| [c[0] as u16, c[1] as u16, c[2] as u16, c[3] as u16])
                .collect(),
            skin_weights: weights
                .chunks_exact(SKIN_SLOTS)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            info,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn avatar(n: usize, sh_degree: usize) -> BakedAvatar {
        let width = 3 * sh::coefficients(sh_degree);
        let v = |i: usize, k: usize| ((i * 31 + k * 7) % 17) as f32 / 17.0 - 0.5;
        BakedAvatar {
            info: AvatarInfo {
                gaussians: n,
                sh_degree,
                joints: 24,
                source: "stage1-00000060".into(),
                steps: 5,
                seconds: 0.5,
                training_psnr: 20.0,
            },
            means: (0..n).map(|i| [v(i, 0), v(i, 1), v(i, 2)]).collect(),
            log_scales: (0..n)
                .map(|i| [v(i, 3) - 4.0, v(i, 4) - 4.0, v(i, 5) - 6.0])
                .collect(),
            rotations: (0..n).map(|i| [1.0, v(i, 6), v(i, 7), v(i, 8)]).collect(),
            opacity_logits: (0..n).map(|i| v(i, 9)).collect(),
            colours: (0..n * width).map(|i| v(i, 10)).collect(),
            skin_joints: (0..n).map(|i| [(i % 24) as u16, 3, 0, 0]).collect(),
            skin_weights: (0..n).map(|_| [0.75, 0.25, 0.0, 0.0]).collect(),
        }
    }

    #[test]
    fn an_avatar_reads_back_as_written_and_its_skin_is_dense_rows_of_its_weights() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("baked");
        for degree in [0, 1] {
            let a = avatar(9, degree);
            a.save(&path).unwrap();
            assert_eq!(BakedAvatar::load(&path).unwrap(), a);
        }
        let a = avatar(3, 0);
        let skin = to_host(a.skin(&anerf_device::cpu_device()));
        for (i, row) in skin.chunks(24).enumerate() {
            let mut expected = [0.0; 24];
            expected[i % 24] += 0.75;
            expected[3] += 0.25;
            assert_eq!(row, expected, "row {i}");
        }
    }

    /// A damaged or inconsistent folder is refused with the file named; an unfinished one (no manifest)
    /// says how to make it again.
    #[test]
    fn damaged_avatars_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("baked");
        avatar(4, 1).save(&path).unwrap();
        let means = path.join("means.npy");
        let mut bytes = std::fs::read(&means).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0x40;
        std::fs::write(&means, &bytes).unwrap();
        let err = format!("{:#}", BakedAvatar::load(&path).unwrap_err());
        assert!(
            err.contains("means.npy") && err.contains("SHA-256"),
            "{err}"
        );

        let mut bad = avatar(4, 1);
        bad.skin_joints[2][1] = 30;
        bad.save(&path).unwrap();
        let err = format!("{:#}", BakedAvatar::load(&path).unwrap_err());
        assert!(
            err.contains("skin_joints.npy") && err.contains("joint 30"),
            "{err}"
        );

        let mut nan = avatar(4, 1);
        nan.opacity_logits[1] = f32::NAN;
        nan.save(&path).unwrap();
        let err = format!("{:#}", BakedAvatar::load(&path).unwrap_err());
        assert!(err.contains("opacity_logits.npy"), "{err}");

        let mut huge = avatar(4, 1);
        huge.info.gaussians = MAX_GAUSSIANS + 1;
        huge.save(&path).unwrap();
        let err = format!("{:#}", BakedAvatar::load(&path).unwrap_err());
        assert!(
            err.contains("avatar.json") && err.contains("at most"),
            "{err}"
        );

        std::fs::remove_file(path.join("manifest.json")).unwrap();
        let err = format!("{:#}", BakedAvatar::load(&path).unwrap_err());
        assert!(err.contains("anerf bake"), "{err}");
    }
}
