//! Volume rendering: depth samples along rays (and, with the model, compositing and losses).

pub mod sampling;

pub use sampling::stratified_depths;
