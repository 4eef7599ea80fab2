//! Every random stream of training, seeded from the experiment's one `seed`.

/// A random stream of the fits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// Stage 1's device stream (parameter initialisation).
    Stage1Device,
    /// Stage 1's ray sampler (frame, view and pixel choice).
    Stage1Rays,
    /// Stage 1's host stream (sample jitter along the rays).
    Stage1Host,
    /// Stage 2's device stream (the novel-pose field's initialisation).
    Stage2Device,
    /// Stage 2's host stream (frame choice, the point sets).
    Stage2Host,
    /// A pose-file fit's device stream.
    PoseFitDevice,
    /// A pose-file fit's host stream.
    PoseFitHost,
}

/// The seed of `stream` in an experiment seeded with `seed`. The streams are independent, and each fit
/// draws the same numbers whether it runs straight or resumed (the host streams are saved in checkpoints).
/// The constants are those every recorded figure was trained with.
pub fn stream_seed(seed: u64, stream: Stream) -> u64 {
    seed ^ match stream {
        Stream::Stage1Device | Stream::Stage1Rays => 0,
        Stream::Stage1Host => 0x5eed_0001,
        Stream::Stage2Device => 2,
        Stream::Stage2Host => 0x5eed_0002,
        Stream::PoseFitDevice => 3,
        Stream::PoseFitHost => 0x5eed_0003,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_streams_of_a_seed_are_distinct() {
        let all = [
            Stream::Stage1Device,
            Stream::Stage1Host,
            Stream::Stage2Device,
            Stream::Stage2Host,
            Stream::PoseFitDevice,
            Stream::PoseFitHost,
        ];
        for seed in [0, 7, u64::MAX] {
            let seeds: Vec<u64> = all.iter().map(|&s| stream_seed(seed, s)).collect();
            for (i, a) in seeds.iter().enumerate() {
                assert!(seeds[i + 1..].iter().all(|b| b != a), "{seeds:?}");
            }
        }
    }
}
