//! The hash-grid CPU kernels alone, on the `fast` preset's canonical-NeRF grid: `cargo bench -p anerf-core
//! --bench hash_grid_kernels [-- POINTS]`. Prints the median and range of each kernel's wall time over
//! repeated calls on 65,536 (or `POINTS`) points drawn uniformly in a 1 m cube around the origin (metres), the
//! `anerf bench` step workload's points, with a random table and output gradient.

use anerf_core::kernels::hash_grid::cpu;
use anerf_core::model::config::{ModelPreset, PointEncoding};
use anerf_testing::{report_ms, Xorshift};

/// Timed calls per kernel, after one untimed call.
const REPEATS: usize = 15;

fn main() {
    let n: usize = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .map(|a| a.parse().expect("POINTS: a number of points"))
        .unwrap_or(65_536);
    let PointEncoding::HashGrid { nerf, .. } = ModelPreset::Fast.config().encoding else {
        panic!("the fast preset encodes with hash grids");
    };
    let spec = nerf.spec();
    let mut random = Xorshift::default();
    let mut uniform = move || random.uniform();
    let points: Vec<f32> = (0..3 * n).map(|_| uniform() - 0.5).collect();
    let table: Vec<f32> = (0..spec.table_rows() * spec.features)
        .map(|_| (uniform() - 0.5) * 2e-2)
        .collect();
    let grad: Vec<f32> = (0..n * spec.output_dim())
        .map(|_| uniform() - 0.5)
        .collect();
    let (mut out, mut grad_table, mut grad_points) = (
        vec![0.0; n * spec.output_dim()],
        vec![0.0; table.len()],
        vec![0.0; 3 * n],
    );
    println!(
        "{n} points, {} levels of 2^{} × {} entries, {} threads",
        spec.levels(),
        spec.table_size.trailing_zeros(),
        spec.features,
        rayon::current_num_threads()
    );
    report_ms("encode", REPEATS, || {
        cpu::encode(&points, &table, &spec, &mut out)
    });
    report_ms("table gradient", REPEATS, || {
        grad_table.fill(0.0);
        cpu::table_grad(&points, &grad, &spec, &mut grad_table)
    });
    report_ms("point gradient", REPEATS, || {
        cpu::points_grad(&points, &table, &grad, &spec, &mut grad_points)
    });
    report_ms("both gradients", REPEATS, || {
        grad_table.fill(0.0);
        cpu::grads(
            &points,
            &table,
            &grad,
            &spec,
            &mut grad_table,
            &mut grad_points,
        )
    });
}
