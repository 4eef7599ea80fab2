//! Gaussians in the PLY layout of 3D Gaussian Splatting, which splat viewers and tools read (SuperSplat,
//! the antimatter15 and PlayCanvas viewers, gsplat): one binary `vertex` element of float properties
//! `x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_* opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3`.
//! Positions in metres; `f_dc` the degree-0 harmonic coefficients (r, g, b); `f_rest` the higher ones
//! channel by channel (every red coefficient, then green, then blue: 3DGS's order); `opacity` a logit;
//! `scale` natural logarithms of the standard deviations; `rot` a quaternion `w x y z`; normals 0.

use std::io::Read;
use std::path::Path;

use anerf_core::gaussians::Splats;
use anerf_data::atomic::write_with;

use crate::error::EvalError;

/// The Gaussians to write and the degree of their harmonics: `splats.colours` holds `3·(d+1)²` coefficients
/// per Gaussian, coefficient-major (`k₀ r g b, k₁ r g b, …`).
#[derive(Debug, Clone, Copy)]
pub struct SplatCloud<'a> {
    pub splats: Splats<'a>,
    pub sh_degree: usize,
}

impl SplatCloud<'_> {
    /// Harmonic coefficients per channel, `(d+1)²`.
    fn coefficients(&self) -> usize {
        (self.sh_degree + 1).pow(2)
    }

    fn validate(&self) -> Result<(), EvalError> {
        let n = self.splats.means.len();
        let invalid = |detail: String| EvalError::InvalidInput {
            what: "Gaussian cloud",
            detail,
        };
        if [
            self.splats.log_scales.len(),
            self.splats.rotations.len(),
            self.splats.opacity_logits.len(),
        ] != [n; 3]
            || self.splats.colours.len() != n * 3 * self.coefficients()
        {
            return Err(invalid(format!(
                "{n} means but {} scales, {} rotations, {} opacities, {} colour values (expected {} per \
                 Gaussian for degree {})",
                self.splats.log_scales.len(),
                self.splats.rotations.len(),
                self.splats.opacity_logits.len(),
                self.splats.colours.len(),
                3 * self.coefficients(),
                self.sh_degree
            )));
        }
        let all = self
            .splats
            .means
            .iter()
            .chain(self.splats.log_scales)
            .flatten()
            .chain(self.splats.rotations.iter().flatten())
            .chain(self.splats.opacity_logits)
            .chain(self.splats.colours);
        if all.clone().any(|v| !v.is_finite()) {
            return Err(invalid("a value is not finite".into()));
        }
        Ok(())
    }
}

/// The property names, in file order, for harmonics of `sh_degree`.
pub fn property_names(sh_degree: usize) -> Vec<String> {
    let rest = 3 * ((sh_degree + 1).pow(2) - 1);
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .map(String::from)
    .to_vec();
    names.extend((0..rest).map(|i| format!("f_rest_{i}")));
    names.push("opacity".into());
    names.extend((0..3).map(|i| format!("scale_{i}")));
    names.extend((0..4).map(|i| format!("rot_{i}")));
    names
}

/// Writes `cloud` to `path` (atomically).
pub fn write_splat_ply(path: &Path, cloud: &SplatCloud) -> Result<(), EvalError> {
    cloud.validate()?;
    let names = property_names(cloud.sh_degree);
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by anerf\nelement vertex {}\n",
        cloud.splats.means.len()
    );
    for name in &names {
        header += &format!("property float {name}\n");
    }
    header += "end_header\n";
    let k = cloud.coefficients();
    let mut bytes = header.into_bytes();
    bytes.reserve(cloud.splats.means.len() * names.len() * 4);
    for i in 0..cloud.splats.means.len() {
        let coefficients = &cloud.splats.colours[i * 3 * k..(i + 1) * 3 * k];
        let mut row: Vec<f32> = cloud.splats.means[i].to_vec();
        row.extend([0.0; 3]);
        row.extend(&coefficients[..3]);
        for channel in 0..3 {
            row.extend((1..k).map(|c| coefficients[3 * c + channel]));
        }
        row.push(cloud.splats.opacity_logits[i]);
        row.extend(cloud.splats.log_scales[i]);
        row.extend(cloud.splats.rotations[i]);
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    write_with(path, |w| {
        w.write_all(&bytes).map_err(|source| EvalError::Io {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Gaussians read from a splat PLY ([`read_splat_ply`]), in [`SplatCloud`]'s layout.
#[derive(Debug, Clone, PartialEq)]
pub struct SplatData {
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 3]>,
    pub rotations: Vec<[f32; 4]>,
    pub opacity_logits: Vec<f32>,
    /// `3·(d+1)²` coefficients per Gaussian, coefficient-major.
    pub colours: Vec<f32>,
    pub sh_degree: usize,
}

impl SplatData {
    /// The Gaussians as [`write_splat_ply`] takes them.
    pub fn cloud(&self) -> SplatCloud<'_> {
        SplatCloud {
            splats: Splats {
                means: &self.means,
                log_scales: &self.log_scales,
                rotations: &self.rotations,
                opacity_logits: &self.opacity_logits,
                colours: &self.colours,
            },
            sh_degree: self.sh_degree,
        }
    }
}

/// Longest header accepted: the layout's is a few hundred bytes for any degree anerf writes.
const MAX_HEADER_BYTES: usize = 64 * 1024;

/// A splat PLY read once: its bytes as they are on disk and the Gaussians they hold, so that a server can
/// send exactly the bytes it checked.
#[derive(Debug, Clone, PartialEq)]
pub struct SplatFile {
    pub bytes: Vec<u8>,
    pub data: SplatData,
}

/// Reads a PLY in the layout [`write_splat_ply`] writes (degree 0 to 3), refusing with the file named:
/// another format or property list, a header claiming more than `max_gaussians` Gaussians (checked before
/// anything is allocated for them), a file shorter or longer than its header says (truncated), a value
/// that is not finite, or a rotation of zero length. Scales are logarithms, so any finite value is a
/// positive scale.
pub fn read_splat_ply(path: &Path, max_gaussians: usize) -> Result<SplatData, EvalError> {
    load_splat_ply(path, max_gaussians).map(|file| file.data)
}

/// [`read_splat_ply`], keeping the file's bytes; a file whose length changes while it is read is refused.
pub fn load_splat_ply(path: &Path, max_gaussians: usize) -> Result<SplatFile, EvalError> {
    let bad = |detail: String| EvalError::Format {
        path: path.to_path_buf(),
        detail,
    };
    let io = |source| EvalError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let length = file.metadata().map_err(io)?.len();
    let mut head = Vec::new();
    (&mut file)
        .take(MAX_HEADER_BYTES as u64)
        .read_to_end(&mut head)
        .map_err(io)?;
    let end = b"end_header\n";
    let at = head
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| {
            bad(format!(
                "no end_header line in its first {MAX_HEADER_BYTES} bytes"
            ))
        })?
        + end.len();
    let header =
        std::str::from_utf8(&head[..at]).map_err(|_| bad("the header is not text".into()))?;
    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err(bad("not a PLY file (no 'ply' line first)".into()));
    }
    let (mut count, mut names) = (None, Vec::new());
    for line in lines {
        match line.split_whitespace().collect::<Vec<_>>().as_slice() {
            ["format", "binary_little_endian", "1.0"] | ["comment", ..] | ["end_header"] => {}
            ["format", other, ..] => {
                return Err(bad(format!(
                    "format {other}; expected binary_little_endian 1.0"
                )))
            }
            ["element", "vertex", n] if count.is_none() => {
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| bad(format!("vertex count '{n}'")))?,
                )
            }
            ["property", "float", name] if count.is_some() => names.push(name.to_string()),
            _ => return Err(bad(format!("unexpected header line '{line}'"))),
        }
    }
    let n = count.ok_or_else(|| bad("no 'element vertex' line".into()))?;
    if n > max_gaussians {
        return Err(bad(format!(
            "{n} Gaussians; at most {max_gaussians} are read"
        )));
    }
    let sh_degree = (0..=3)
        .find(|&d| property_names(d) == names)
        .ok_or_else(|| {
            bad(format!(
                "properties {}; expected 3D Gaussian Splatting's (x y z nx ny nz f_dc_0..2 f_rest_* opacity \
                 scale_0..2 rot_0..3) of degree 0 to 3",
                names.join(" ")
            ))
        })?;
    let width = names.len();
    let expected = at as u64 + (n * width * 4) as u64;
    if length != expected {
        return Err(bad(format!(
            "{length} bytes; {n} Gaussians of {width} floats after the header make {expected} (truncated \
             or trailing data)"
        )));
    }
    let mut bytes = head;
    file.read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 != length {
        return Err(bad(format!(
            "{} bytes read where it had {length}: the file changed while it was read",
            bytes.len()
        )));
    }
    let values: Vec<f32> = bytes[at..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!(
            "Gaussian {}'s {} is {}",
            i / width,
            names[i % width],
            values[i]
        )));
    }
    let k = (sh_degree + 1).pow(2);
    let mut data = SplatData {
        means: Vec::with_capacity(n),
        log_scales: Vec::with_capacity(n),
        rotations: Vec::with_capacity(n),
        opacity_logits: Vec::with_capacity(n),
        colours: Vec::with_capacity(n * 3 * k),
        sh_degree,
    };
    for (i, row) in values.chunks_exact(width).enumerate() {
        let rest = &row[9..9 + 3 * (k - 1)];
        let tail = &row[9 + 3 * (k - 1)..];
        let rotation = [tail[4], tail[5], tail[6], tail[7]];
        if rotation.iter().all(|&q| q == 0.0) {
            return Err(bad(format!("Gaussian {i}'s rotation is zero")));
        }
        data.means.push([row[0], row[1], row[2]]);
        data.colours.extend(&row[6..9]);
        for c in 1..k {
            data.colours
                .extend((0..3).map(|channel| rest[channel * (k - 1) + c - 1]));
        }
        data.opacity_logits.push(tail[0]);
        data.log_scales.push([tail[1], tail[2], tail[3]]);
        data.rotations.push(rotation);
    }
    Ok(SplatFile { bytes, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An independent reader of the layout: the header's property names and the float rows.
    fn read(path: &Path) -> (Vec<String>, usize, Vec<f32>) {
        let bytes = std::fs::read(path).unwrap();
        let end = b"end_header\n";
        let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        let header = std::str::from_utf8(&bytes[..at]).unwrap();
        let mut names = Vec::new();
        let mut count = 0;
        for line in header.lines() {
            let words: Vec<&str> = line.split_whitespace().collect();
            match words.as_slice() {
                ["format", f, "1.0"] => assert_eq!(*f, "binary_little_endian"),
                ["element", "vertex", n] => count = n.parse().unwrap(),
                ["property", "float", name] => names.push(name.to_string()),
                _ => {}
            }
        }
        let values = bytes[at..]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        (names, count, values)
    }

    #[test]
    fn rows_hold_3dgs_properties_with_the_higher_harmonics_channel_by_channel() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.ply");
        let means = [[0.1, 0.2, 0.3], [-1.0, 2.0, 0.5]];
        let log_scales = [[-4.0, -4.5, -6.0], [-3.0, -3.5, -5.0]];
        let rotations = [[1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5]];
        let opacity_logits = [2.0, -1.0];
        // Coefficient-major: k0 (r g b), k1 (r g b), k2, k3, with value 10·k + channel (+100 for the second).
        let colours: Vec<f32> = (0..2)
            .flat_map(|i| {
                (0..4).flat_map(move |k| (0..3).map(move |c| (100 * i + 10 * k + c) as f32))
            })
            .collect();
        let cloud = SplatCloud {
            splats: Splats {
                means: &means,
                log_scales: &log_scales,
                rotations: &rotations,
                opacity_logits: &opacity_logits,
                colours: &colours,
            },
            sh_degree: 1,
        };
        write_splat_ply(&path, &cloud).unwrap();
        let (names, count, values) = read(&path);
        assert_eq!(count, 2);
        assert_eq!(names.len(), 6 + 3 + 9 + 1 + 3 + 4);
        assert_eq!(values.len(), 2 * names.len());
        let row = |i: usize, name: &str| {
            values[i * names.len() + names.iter().position(|n| n == name).unwrap()]
        };
        for i in 0..2 {
            let base = 100.0 * i as f32;
            assert_eq!([row(i, "x"), row(i, "y"), row(i, "z")], means[i]);
            assert_eq!([row(i, "nx"), row(i, "ny"), row(i, "nz")], [0.0; 3]);
            assert_eq!(
                [row(i, "f_dc_0"), row(i, "f_dc_1"), row(i, "f_dc_2")],
                [base, base + 1.0, base + 2.0]
            );
            // f_rest: red k1..k3, green k1..k3, blue k1..k3.
            for channel in 0..3 {
                for k in 1..4 {
                    let name = format!("f_rest_{}", channel * 3 + k - 1);
                    assert_eq!(row(i, &name), base + (10 * k + channel) as f32, "{name}");
                }
            }
            assert_eq!(row(i, "opacity"), opacity_logits[i]);
            assert_eq!(
                [row(i, "scale_0"), row(i, "scale_1"), row(i, "scale_2")],
                log_scales[i]
            );
            assert_eq!(
                [
                    row(i, "rot_0"),
                    row(i, "rot_1"),
                    row(i, "rot_2"),
                    row(i, "rot_3")
                ],
                rotations[i]
            );
        }
        let short = SplatCloud {
            splats: Splats {
                opacity_logits: &opacity_logits[..1],
                ..cloud.splats
            },
            ..cloud
        };
        assert!(write_splat_ply(&dir.path().join("b.ply"), &short).is_err());
        assert!(!dir.path().join("b.ply").exists());
    }

    fn two_gaussians(dir: &Path) -> (std::path::PathBuf, SplatData) {
        let data = SplatData {
            means: vec![[0.1, 0.2, 0.3], [-1.0, 2.0, 0.5]],
            log_scales: vec![[-4.0, -4.5, -6.0], [-3.0, -3.5, -5.0]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5]],
            opacity_logits: vec![2.0, -1.0],
            colours: (0..24).map(|v| v as f32 * 0.1).collect(),
            sh_degree: 1,
        };
        let path = dir.join("a.ply");
        write_splat_ply(&path, &data.cloud()).unwrap();
        (path, data)
    }

    /// The Gaussians read back as written; loaded whole, the bytes kept are the file's.
    #[test]
    fn a_written_cloud_reads_back_with_its_count_and_attributes() {
        let dir = tempfile::tempdir().unwrap();
        let (path, data) = two_gaussians(dir.path());
        assert_eq!(read_splat_ply(&path, 2).unwrap(), data);
        let file = load_splat_ply(&path, 2).unwrap();
        assert_eq!(file.data, data);
        assert_eq!(file.bytes, std::fs::read(&path).unwrap());
    }

    /// Truncated, over the limit, non-finite, a zero rotation, another format: refused naming the file.
    #[test]
    fn a_bad_splat_file_is_refused_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let (path, _) = two_gaussians(dir.path());
        let bytes = std::fs::read(&path).unwrap();
        let header = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        let width = 6 + 3 + 9 + 1 + 3 + 4;
        let float_at =
            |gaussian: usize, property: usize| header + 4 * (gaussian * width + property);
        let with = |name: &str, edit: &dyn Fn(&mut Vec<u8>)| {
            let mut b = bytes.clone();
            edit(&mut b);
            let p = dir.path().join(name);
            std::fs::write(&p, b).unwrap();
            p
        };
        let cases: Vec<(std::path::PathBuf, usize, &str)> = vec![
            (
                with("short.ply", &|b| b.truncate(b.len() - 3)),
                2,
                "truncated",
            ),
            (path.clone(), 1, "at most 1"),
            (
                with("nan.ply", &|b| {
                    let at = float_at(1, 21);
                    b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
                }),
                2,
                "scale_2 is NaN",
            ),
            (
                with("zero.ply", &|b| {
                    let at = float_at(0, 22);
                    b[at..at + 16].fill(0);
                }),
                2,
                "rotation is zero",
            ),
            (
                with("ascii.ply", &|b| {
                    let text = String::from_utf8_lossy(&b[..header])
                        .replace("binary_little_endian", "ascii");
                    b.splice(..header, text.into_bytes());
                }),
                2,
                "expected binary_little_endian",
            ),
            (
                with("huge.ply", &|b| {
                    let text = String::from_utf8_lossy(&b[..header])
                        .replace("vertex 2", "vertex 99999999999");
                    b.splice(..header, text.into_bytes());
                }),
                1_000_000,
                "at most 1000000",
            ),
        ];
        for (file, max, why) in cases {
            let err = read_splat_ply(&file, max).unwrap_err().to_string();
            assert!(
                err.contains(&file.display().to_string()) && err.contains(why),
                "{why}: {err}"
            );
        }
    }
}
