//! Small helpers between host memory and Burn tensors.

use burn::module::{ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

/// Reads a float tensor back to the host as `f32`, row-major.
///
/// Panics only when the backend cannot read back synchronously (never on the CPU backends).
pub fn to_host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.try_into_vec_as::<f32>()
        .expect("reading a tensor back to the host")
}

/// A `[rows, cols]` tensor from row-major host data.
pub fn from_rows(data: &[f32], rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    assert_eq!(
        data.len(),
        rows * cols,
        "from_rows: {} values for a {rows}×{cols} tensor",
        data.len()
    );
    Tensor::<1>::from_floats(data, device).reshape([rows, cols])
}

/// `module` with every parameter initialised now, in the module's visiting order. Burn initialises a
/// parameter lazily, drawing from the device's random stream when it is first read, so without this the
/// values a seed gives depend on the order the code first touches the parameters: a forward pass reads
/// them in one order, a copy to another device (data-parallel replicas) in another.
pub fn materialised<M: Module>(module: M) -> M {
    struct Touch;
    impl ModuleVisitor for Touch {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let _ = param.val();
        }
    }
    module.visit(&mut Touch);
    module
}

/// The gradient of every float parameter of `module`, read back to the host in the module's visiting order
/// (`None` where `grads` holds none): for checking where gradients reach and comparing them across backends.
pub fn parameter_gradients<M: Module>(
    module: &M,
    grads: &GradientsParams,
) -> Vec<Option<Vec<f32>>> {
    struct Collect<'a> {
        grads: &'a GradientsParams,
        values: Vec<Option<Vec<f32>>>,
    }
    impl ModuleVisitor for Collect<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.values.push(self.grads.get::<D>(param.id).map(to_host));
        }
    }
    let mut collect = Collect {
        grads,
        values: Vec::new(),
    };
    module.visit(&mut collect);
    collect.values
}
