//! Writes a synthetic subject preset and prints how long each stage took.
//!
//! `cargo run -p anerf-data --example synth_timing -- <tiny|demo> <new output folder>`

use anerf_data::synthetic::{write_subject, SyntheticSpec};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [preset, out] = args.as_slice() else {
        return Err("usage: synth_timing <tiny|demo> <new output folder>".into());
    };
    let spec = match preset.as_str() {
        "tiny" => SyntheticSpec::tiny(),
        "demo" => SyntheticSpec::demo(),
        other => return Err(format!("unknown preset {other:?} (expected tiny or demo)").into()),
    };
    let summary = write_subject(&spec, std::path::Path::new(out))?;
    let t = summary.timings;
    println!(
        "{preset}: {} views × {} frames at {} px, {} vertices, {} faces, {} threads",
        summary.subject.cameras.len(),
        summary.subject.frames.len(),
        spec.rig.resolution,
        summary.subject.body.canonical_vertices.len(),
        summary.subject.body.faces.len(),
        rayon::current_num_threads()
    );
    println!(
        "body + poses {:.2?}, images {:.2?}, arrays {:.2?}, total {:.2?}",
        t.body, t.images, t.arrays, t.total
    );
    Ok(())
}
