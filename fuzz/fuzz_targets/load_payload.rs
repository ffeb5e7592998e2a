//! The checksum stops almost every mutation of a whole file at the header, so this target
//! frames the fuzzer's bytes with a valid header and CRC: it exercises bincode decoding and
//! validation of arbitrary payloads. Anything accepted must also run a rollout.
//!
//! Run: `cargo fuzz run load_payload -- -max_total_time=600` (seeds: `fuzz/seed_corpus.sh`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use pinc::model::{FORMAT_VERSION, MAGIC, PincModel};
use pinc::runtime::Predictor;
use pinc::{Input, State};

fuzz_target!(|payload: &[u8]| {
    let mut file = MAGIC.to_vec();
    file.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    file.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    file.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    file.extend_from_slice(payload);
    if let Ok(model) = PincModel::from_bytes(&file) {
        let p = Predictor::new(&model);
        let mut ws = p.workspace();
        let mut traj = [State::zeros(); 4];
        let x = State::from([0.1, 0.0, 0.2, 1.0, 0.0, 0.1, 0.0, 0.0, 0.0]);
        let _ = p.rollout(&mut ws, &x, &[Input::new(1.0, 0.0, 2.0, 0.1); 3], &mut traj);
    }
});
