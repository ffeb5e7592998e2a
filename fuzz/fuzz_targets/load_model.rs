//! Any byte string given to the `.pinc` loader yields a model or a typed error, never a
//! panic, and a model it accepts runs a step without panicking.
//!
//! Run: `cargo fuzz run load_model -- -max_total_time=600` from the repository root
//! (the seed corpus is built by `fuzz/seed_corpus.sh`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use pinc::model::PincModel;
use pinc::runtime::Predictor;
use pinc::{Input, State};

fuzz_target!(|data: &[u8]| {
    if let Ok(model) = PincModel::from_bytes(data) {
        let p = Predictor::new(&model);
        let mut ws = p.workspace();
        let mut out = State::zeros();
        let x = State::from([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let _ = p.step(&mut ws, &x, &Input::zeros(), &mut out);
    }
});
