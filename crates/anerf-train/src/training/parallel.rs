//! Data-parallel training on several devices with Burn's distributed data parallel: one copy of the model
//! (a replica) and its optimiser per device, each fed a contiguous shard of every step's ray batch in its
//! own thread. The replicas' parameters are marked distributed, so Burn all-reduces (averages) their
//! gradients during each backward pass; every replica then takes the same optimiser step and the copies
//! stay equal. Burn 0.22.1 implements the all-reduce for CUDA devices only (NCCL); docs/GPU.md says more.
//!
//! The shards' losses are weighted so that their average is the loss of the whole batch: a mean over rays
//! or samples is summed on each shard and divided by the count over all shards, which the shards exchange
//! on the host before their backward passes ([`Shard::sum`]). A one-device fit is the case of one shard.

use std::ops::Range;
use std::sync::{Barrier, Mutex};

use anerf_core::model::AnimatableNerf;
use anyhow::Result;
use burn::module::{Module, ModuleMapper, Param};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use burn::tensor::distributed::{DistributedConfig, DistributedContext, ReduceOperation};

use super::driver::{Advance, Fit};
use super::window::StepValues;

/// One replica's part of a step: shard `index` of `count`, and the exchange through which the shards of a
/// step add up their counts.
pub struct Shard<'a> {
    pub index: usize,
    pub count: usize,
    exchange: &'a Exchange,
}

impl Shard<'_> {
    /// This shard's part of `len` items: contiguous, the parts' sizes differing by at most one.
    pub fn part(&self, len: usize) -> Range<usize> {
        let at = |k: usize| k * len / self.count;
        at(self.index)..at(self.index + 1)
    }

    /// The sums over every shard of the step of `values` (this shard's), for exchange round `round`;
    /// waits until every shard has given its values for that round.
    pub fn sum(&self, round: usize, values: &[f64]) -> Vec<f64> {
        self.exchange.combine(round, values, |a, b| a + b)
    }

    /// The greatest over every shard of `value` (this shard's), for exchange round `round`.
    pub fn max(&self, round: usize, value: f64) -> f64 {
        self.exchange.combine(round, &[value], f64::max)[0]
    }
}

/// The host-side meeting point of a step's shards: per round, what they gave so far, combined.
struct Exchange {
    barrier: Barrier,
    rounds: Mutex<Vec<Option<Vec<f64>>>>,
}

impl Exchange {
    fn new(shards: usize) -> Self {
        Self {
            barrier: Barrier::new(shards),
            rounds: Mutex::new(Vec::new()),
        }
    }

    /// `values` combined entry by entry with every other shard's of round `round` by `op`; waits for all.
    fn combine(&self, round: usize, values: &[f64], op: fn(f64, f64) -> f64) -> Vec<f64> {
        {
            let mut rounds = self.rounds.lock().unwrap_or_else(|e| e.into_inner());
            if rounds.len() <= round {
                rounds.resize(round + 1, None);
            }
            rounds[round] = Some(match rounds[round].take() {
                None => values.to_vec(),
                Some(so_far) => so_far.iter().zip(values).map(|(a, b)| op(*a, *b)).collect(),
            });
        }
        self.barrier.wait();
        let rounds = self.rounds.lock().unwrap_or_else(|e| e.into_inner());
        rounds[round].clone().expect("every shard gave its values")
    }
}

/// The exchange round in which the shards agree whether every loss is finite (the steps' own rounds come
/// before it).
const FINITE_ROUND: usize = 8;

/// A step that can be split into shards, one per replica of a data-parallel fit (stage 1).
pub(super) trait ShardedStep: Sync {
    /// The host-side part of the next step, done once for all `replicas`: what to fit, and the inputs each
    /// replica's device needs.
    type Batch: Sync;
    fn batch(&mut self, replicas: usize) -> Result<Self::Batch>;
    /// The loss of `shard` of `batch` on `model` (its replica's), weighted so that the mean over the shards
    /// is the batch's loss, and its values for the log likewise; called from every replica's thread at
    /// once.
    fn shard_loss(
        &self,
        batch: &Self::Batch,
        shard: &Shard<'_>,
        model: &AnimatableNerf,
    ) -> Result<(Tensor<1>, StepValues)>;
}

/// The loss of a whole step on one model: the step as its only shard.
pub(super) fn whole_loss<S: ShardedStep>(
    step: &mut S,
    model: &AnimatableNerf,
) -> Result<(Tensor<1>, StepValues)> {
    let batch = step.batch(1)?;
    let exchange = Exchange::new(1);
    let shard = Shard {
        index: 0,
        count: 1,
        exchange: &exchange,
    };
    step.shard_loss(&batch, &shard, model)
}

/// Runs `work` once per shard of a step split `count` ways, each in its own thread with its [`Shard`] (the
/// shards meet in its exchange rounds); returns the results in shard order.
pub(super) fn run_shards<T: Send>(count: usize, work: impl Fn(Shard<'_>) -> T + Sync) -> Vec<T> {
    let exchange = Exchange::new(count);
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..count)
            .map(|index| {
                let (exchange, work) = (&exchange, &work);
                scope.spawn(move || {
                    work(Shard {
                        index,
                        count,
                        exchange,
                    })
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    })
}

/// Marks every float parameter distributed, so that Burn all-reduces its gradient in each backward pass.
struct Distribute;

impl ModuleMapper for Distribute {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, tensor, mapper) = param.consume();
        Param::from_mapped_value(id, tensor.set_distributed(id), mapper)
    }
}

/// The replicas of a data-parallel fit, one per device, with their optimisers; replica 0 is the one
/// validated, checkpointed and returned.
pub(super) struct Replicas {
    models: Vec<AnimatableNerf>,
    optims: Vec<ModuleOptimizer>,
    /// Keeps Burn's gradient all-reduce running while the fit runs; dropped after the models.
    _context: DistributedContext,
}

impl Replicas {
    /// Copies of `model` on each of `devices` (with autodiff; `model` on the first), with the optimisers
    /// `optims` (one per device, on its device), their parameters marked distributed.
    pub fn new(model: AnimatableNerf, optims: Vec<ModuleOptimizer>, devices: &[Device]) -> Self {
        assert_eq!(optims.len(), devices.len(), "one optimiser per device");
        let context = DistributedContext::init(
            devices.to_vec(),
            DistributedConfig {
                all_reduce_op: ReduceOperation::Mean,
            },
        );
        let models = devices
            .iter()
            .map(|d| model.clone().fork(d).map(&mut Distribute))
            .collect();
        Self {
            models,
            optims,
            _context: context,
        }
    }
}

/// What one replica's thread returns: its model and optimiser after the step, and the step's values (or
/// the non-finite loss that stopped it).
type ReplicaStep = (AnimatableNerf, ModuleOptimizer, Advance);

/// One replica's step: its shard's loss, the agreement that every shard's loss is finite (else no replica
/// runs a backward pass, which would wait for the others' gradients), the backward pass (which all-reduces
/// the gradients) and the optimiser step.
fn replica_step<S: ShardedStep>(
    step: &S,
    batch: &S::Batch,
    shard: &Shard<'_>,
    model: AnimatableNerf,
    mut optim: ModuleOptimizer,
    lr: f64,
) -> Result<ReplicaStep> {
    let outcome = step.shard_loss(batch, shard, &model);
    let finite = matches!(&outcome, Ok((_, v)) if v.loss.is_finite());
    let bad = shard.sum(FINITE_ROUND, &[f64::from(u8::from(!finite))])[0];
    let (loss, values) = outcome?;
    if bad > 0.0 {
        return Ok((model, optim, Advance::NonFinite(values.loss)));
    }
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    let model = optim.step(lr, model, grads);
    Ok((model, optim, Advance::Stepped(values)))
}

/// The shards' values as one step's: the means of the weighted values (the batch's), the items summed.
fn combine(values: &[StepValues]) -> StepValues {
    let n = values.len() as f32;
    let mean = |f: fn(&StepValues) -> f32| values.iter().map(f).sum::<f32>() / n;
    StepValues {
        loss: mean(|v| v.loss),
        mse: mean(|v| v.mse),
        blend: mean(|v| v.blend),
        surviving: mean(|v| v.surviving),
        occupied: mean(|v| v.occupied),
        items: values.iter().map(|v| v.items).sum(),
    }
}

impl<S: ShardedStep + super::driver::Step> Fit<S> for Replicas {
    fn advance(&mut self, step: &mut S, lr: f64) -> Result<Advance> {
        let n = self.models.len();
        let batch = step.batch(n)?;
        let step: &S = step;
        // Each replica's thread takes its model and optimiser from its slot; its result returns them.
        let slots: Vec<Mutex<Option<(AnimatableNerf, ModuleOptimizer)>>> = self
            .models
            .drain(..)
            .zip(self.optims.drain(..))
            .map(|r| Mutex::new(Some(r)))
            .collect();
        let results = run_shards(n, |shard| {
            let (model, optim) = slots[shard.index]
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .take()
                .expect("each replica is taken once");
            replica_step(step, &batch, &shard, model, optim, lr)
        });
        let mut values = Vec::with_capacity(n);
        let mut non_finite = None;
        for result in results {
            let (model, optim, advance) = result?;
            self.models.push(model);
            self.optims.push(optim);
            match advance {
                Advance::Stepped(v) => values.push(v),
                Advance::NonFinite(loss) => non_finite = non_finite.or(Some(loss)),
            }
        }
        Ok(match non_finite {
            Some(loss) => Advance::NonFinite(loss),
            None => Advance::Stepped(combine(&values)),
        })
    }

    fn model(&self) -> &AnimatableNerf {
        &self.models[0]
    }

    fn optim(&self) -> &ModuleOptimizer {
        &self.optims[0]
    }

    fn models_mut(&mut self) -> Vec<&mut AnimatableNerf> {
        self.models.iter_mut().collect()
    }

    fn into_model(mut self) -> AnimatableNerf {
        self.models.swap_remove(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_split_a_batch_into_contiguous_parts_of_near_equal_size() {
        let exchange = Exchange::new(1);
        for (len, count) in [(10, 3), (4096, 2), (5, 5), (7, 1)] {
            let parts: Vec<Range<usize>> = (0..count)
                .map(|index| {
                    Shard {
                        index,
                        count,
                        exchange: &exchange,
                    }
                    .part(len)
                })
                .collect();
            assert_eq!(parts[0].start, 0);
            assert_eq!(parts[count - 1].end, len);
            for w in parts.windows(2) {
                assert_eq!(w[0].end, w[1].start, "{len} in {count}: contiguous");
            }
            let sizes: Vec<usize> = parts.iter().map(|p| p.len()).collect();
            let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
            assert!(hi - lo <= 1, "{len} in {count}: {sizes:?}");
        }
    }

    #[test]
    fn the_exchange_combines_each_round_over_every_shard() {
        let sums = run_shards(3, |shard| {
            let k = shard.index as f64;
            (
                shard.sum(0, &[k, 1.0]),
                shard.sum(1, &[10.0 * k]),
                shard.max(2, -k),
            )
        });
        assert_eq!(sums.len(), 3);
        for (first, second, third) in sums {
            assert_eq!(first, vec![3.0, 3.0]);
            assert_eq!(second, vec![30.0]);
            assert_eq!(third, 0.0);
        }
    }
}
